//! A shot's row from its hemisphere: drawn fresh (hybrid or delta form
//! factors), a split shot's groups and their assembly, the normalisers
//! that keep a closed scene's energy, and the sums over the ranks.

use super::*;

impl GpuFormFactors<'_> {
    /// The row of a shooter drawn afresh, and the time spent in exchanges.
    pub(super) fn fresh_row(
        &mut self,
        shooter: u32,
        centre: glam::Vec3,
        tier: usize,
    ) -> Result<(Row, Duration), RenderError> {
        match self.method {
            FormFactorMethod::Hemisphere => {
                let exchange = self.hemisphere(shooter, centre, tier, f32::INFINITY)?;
                self.timings.receivers += self.pairs.len() as u64;
                let (sums, more) = self.sum_over_ranks(vec![self.view[1]]);
                let row = Row {
                    columns: 1,
                    ids: self.pairs.iter().map(|p| p.0).collect(),
                    values: self.pairs.iter().map(|p| p.1 as f64 / FIXED_ONE).collect(),
                    blocked: vec![sums[0] as f64 / formfactor::SHARE_ONE],
                    ..Row::default()
                };
                Ok((row, exchange + more))
            }
            FormFactorMethod::Hybrid => self.hybrid_row(shooter, centre, tier),
        }
    }

    /// The hybrid row of the hemisphere of `shooter` at `centre`, redrawn
    /// split into groups of the shooter's elements where visibility varies
    /// across it.
    pub(super) fn hybrid_row(
        &mut self,
        shooter: u32,
        centre: glam::Vec3,
        tier: usize,
    ) -> Result<(Row, Duration), RenderError> {
        let (first, mut exchange) = self.hybrid_first(shooter, centre, tier)?;
        let mut split = match first {
            First::Whole(row) => return Ok((row, exchange)),
            First::Split(split) => split,
        };
        let mut views = Vec::with_capacity(3 * split.groups.len());
        for g in 0..split.groups.len() {
            let (part, spent) = self.group_row(&split.groups[g], shooter, tier)?;
            exchange += spent;
            split.row.merge(&part);
            views.extend(self.view);
        }
        let (row, spent) = self.finish_split(split, &views);
        Ok((row, exchange + spent))
    }

    /// The hybrid row of the hemisphere of `shooter` at `centre` (drawn
    /// here), or, where a near
    /// receiver is partly hidden from the shooter's centre (visibility
    /// varies across the shooter), the start of a split shot: that row
    /// without its near receivers, which each group of the shooter's
    /// elements then looks at for itself ([`Self::group_row`]).
    pub(super) fn hybrid_first(
        &mut self,
        shooter: u32,
        centre: glam::Vec3,
        tier: usize,
    ) -> Result<(First, Duration), RenderError> {
        let drawn = self.whole_with_far(shooter, centre, tier)?;
        let m = self.mesh.patches[shooter as usize].elements.len();
        let columns = if m <= formfactor::MAX_SHOOTER_COLUMNS {
            m
        } else {
            1
        };
        self.timings.receivers += self.visible_receivers();
        let mut row =
            formfactor::hybrid_row(self.mesh, &self.receivers, shooter, &self.pairs, 0..columns);
        if let Some(p) = self.penumbra.get_mut(shooter as usize) {
            *p = [row.partial + row.near_hidden, row.total + row.near_hidden];
        }
        let v = self.view;
        let mut parts = vec![row.near_hidden, row.total, v[0], v[1], v[2]];
        parts.extend(row.column_totals());
        let (sums, more) = self.sum_over_ranks(parts);
        let exchange = drawn + more;
        // The refinement passes measure with one hemisphere a shot, as
        // coarse as the shot (the emitters' shots split as in the solve).
        let split = self.split && !(self.choice.measuring && tier > 0);
        if !(split && columns > 1 && formfactor::needs_split(sums[0], sums[1])) {
            let scales = self.normalisers(shooter, 0..columns, [sums[2], sums[4]], &sums[5..]);
            row.scale_columns(&scales);
            row.blocked = vec![sums[3] as f64 / formfactor::SHARE_ONE; columns];
            return Ok((First::Whole(row), exchange));
        }
        // Only near receivers look again; farther ones keep this
        // hemisphere's visibility.
        let (is_near, _) = formfactor::near_receivers(self.mesh, shooter);
        let stats = (row.near_hidden, row.total, row.partial);
        row.retain(|j| !is_near(j));
        let split = Split {
            shooter,
            columns,
            row,
            stats,
            groups: formfactor::split_groups(self.mesh, shooter, columns),
        };
        Ok((First::Split(split), exchange))
    }

    /// One group of a split shot's elements looking from its own point
    /// `at`: a segment from a point of the shooter to a near receiver stays
    /// within `near` of the shooter's centre, so only polygons that close
    /// can hide it, and the group draws only those (in a big scene, a small
    /// part of it). Its row holds near receivers only; `self.view` is what
    /// its hemisphere showed (see [`Self::view_of`]).
    pub(super) fn group_row(
        &mut self,
        (group, at): &(std::ops::Range<usize>, glam::Vec3),
        shooter: u32,
        tier: usize,
    ) -> Result<(Row, Duration), RenderError> {
        let (is_near, near) = formfactor::near_receivers(self.mesh, shooter);
        let patch_centre = self.mesh.patches[shooter as usize].centre;
        let reach = near as f32 + at.distance(patch_centre);
        let exchange = self.hemisphere(shooter, *at, tier, reach)?;
        // Its own far receivers, near ones only (few rays).
        let within = reach + self.max_patch_radius;
        self.add_far_receivers((shooter, *at), tier, (within, &is_near), None);
        self.timings.receivers += self.visible_receivers();
        let mut part = formfactor::hybrid_row(
            self.mesh,
            &self.receivers,
            shooter,
            &self.pairs,
            group.clone(),
        );
        part.retain(&is_near);
        Ok((part, exchange))
    }

    /// A split shot's row once every group's part is merged into it:
    /// `views` holds each group's view shares (three a group, over this
    /// rank's cells).
    pub(super) fn finish_split(&mut self, split: Split, views: &[u64]) -> (Row, Duration) {
        let Split {
            shooter,
            columns,
            mut row,
            stats,
            groups,
        } = split;
        (row.near_hidden, row.total, row.partial) = stats;
        // Each group's columns normalised to what its hemisphere (beyond its
        // reach, the first one) saw, as the row of an unsplit shot is.
        let mut parts = row.column_totals();
        let n = parts.len();
        parts.extend_from_slice(views);
        let (sums, exchange) = self.sum_over_ranks(parts);
        let (totals, views) = sums.split_at(n);
        row.blocked = vec![0.0; columns];
        let mut scales = vec![1.0; columns];
        for ((group, _), v) in groups.iter().zip(views.chunks_exact(3)) {
            let s = self.normalisers(shooter, group.clone(), [v[0], v[2]], totals);
            for k in group.clone() {
                scales[k] = s[k];
                row.blocked[k] = v[1] as f64 / formfactor::SHARE_ONE;
            }
        }
        row.scale_columns(&scales);
        self.timings.split += 1;
        (row, exchange)
    }

    /// Where the hemisphere is closed (every cell shows an element or a
    /// back face; `[seen share, empty cells]` over every rank), the scales
    /// that make each column of a hybrid row sum to what it saw times the
    /// column's share of the shooter's area. Light that meets geometry in
    /// every direction must land somewhere, so the row must sum to the seen
    /// share exactly, and the analytic integrals times visibilities do not
    /// (they lose light at near receivers and between them, or create some:
    /// 0.6-2 % in closed rooms); with this a closed scene keeps its energy
    /// (the row-sum normalisation of view-factor codes). Where some cells
    /// see out of the scene, the seen share carries the cells' sampling
    /// error at every silhouette against the outside, which the analytic
    /// row is free of, so the row stays as computed. Only the columns in
    /// `group` are scaled; `totals` are every column's sums over every rank.
    pub(super) fn normalisers(
        &self,
        shooter: u32,
        group: std::ops::Range<usize>,
        [seen, empty]: [u64; 2],
        totals: &[u64],
    ) -> Vec<f64> {
        (0..totals.len())
            .map(|k| {
                if empty > 0 || !group.contains(&k) || totals[k] == 0 {
                    return 1.0;
                }
                let share = if totals.len() == 1 {
                    1.0
                } else {
                    self.area_share(shooter, k..k + 1)
                };
                share * seen as f64 / totals[k] as f64
            })
            .collect()
    }

    /// The share of the shooter patch's area its elements `group` hold.
    pub(super) fn area_share(&self, shooter: u32, group: std::ops::Range<usize>) -> f64 {
        let patch = &self.mesh.patches[shooter as usize];
        let first = patch.elements.start as usize;
        let area: f64 = self.mesh.elements[first + group.start..first + group.end]
            .iter()
            .map(|e| e.area)
            .sum();
        area / patch.area
    }

    /// `parts` summed over ranks (exactly: integers below 2^53), and the
    /// time spent in the collective.
    pub(super) fn sum_over_ranks(&self, parts: Vec<u64>) -> (Vec<u64>, Duration) {
        if self.comm.size() == 1 {
            return (parts, Duration::ZERO);
        }
        let t = Instant::now();
        let n = parts.len();
        let all = self
            .comm
            .all_gather_f64(&parts.iter().map(|&x| x as f64).collect::<Vec<_>>());
        let mut sum = vec![0u64; n];
        for c in all.chunks_exact(n) {
            for (s, x) in sum.iter_mut().zip(c) {
                *s += *x as u64;
            }
        }
        (sum, t.elapsed())
    }
}
