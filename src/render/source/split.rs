//! Split shots in pieces: the first hemisphere of a shot whose visibility
//! varies across the shooter, then one reach-limited hemisphere per group
//! of its elements, then the merged row. A batched solve deals the groups'
//! hemispheres over its ranks as work of their own (a split shot draws up
//! to five hemispheres, and a batch on many ranks waited for its dearest
//! row); the row is assembled on the rank that drew the first, in group
//! order, so its bits are those of a shot drawn whole on one rank. Part of
//! [`GpuFormFactors`] (its fields are this module's parent's).

use super::GpuFormFactors;
use crate::formfactor::{self, Row};
use crate::parallel;
use crate::render::cache::RowKey;
use crate::render::options::RenderError;
use crate::solver::{ShotRegion, Transfer};
use std::ops::Range;
use std::time::{Duration, Instant};

/// A hybrid row after its first hemisphere.
pub(super) enum First {
    /// The row: visibility does not vary across the shooter.
    Whole(Row),
    /// A split shot waiting for its groups.
    Split(Split),
}

/// A split shot between its first hemisphere and its groups'.
pub(super) struct Split {
    pub(super) shooter: u32,
    pub(super) columns: usize,
    /// The first hemisphere's row without its near receivers: the groups'
    /// parts are merged into it.
    pub(super) row: Row,
    /// The first hemisphere's (near hidden, total, partial) shares.
    pub(super) stats: (u64, u64, u64),
    /// Each group's columns and the point it looks from.
    pub(super) groups: Vec<(Range<usize>, glam::Vec3)>,
}

/// What [`GpuFormFactors::start_row`] left.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Started {
    /// The row is in `out`.
    Row,
    /// A split shot with this many groups, each to draw
    /// ([`GpuFormFactors::group_part`]) before
    /// [`GpuFormFactors::finish_row`] assembles its row.
    Split(usize),
}

/// One group of a split shot, drawn on any rank, for the rank that
/// assembles the shot's row.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GroupPart {
    /// The group's near receivers (ids and values, every column).
    pub row: Row,
    /// The shares of its hemisphere's drawn cells that show an element
    /// and a back face (SHARE_ONE fixed point).
    pub seen: [u64; 2],
    /// Its cells that show nothing (beyond its reach), as runs: there the
    /// shot's first hemisphere stands in (see `GpuFormFactors::view_of`).
    pub empty: Vec<u32>,
}

/// Words of a packed part before its receivers.
const HEADER: usize = 9;

impl GroupPart {
    /// Appends the part of row `index` of a batch, group `group`, to `out`
    /// (values as their bits: the row is assembled exactly).
    pub fn pack(&self, index: usize, group: usize, out: &mut Vec<u32>) {
        let split = |x: u64| [x as u32, (x >> 32) as u32];
        out.extend([
            index as u32,
            group as u32,
            self.row.ids.len() as u32,
            self.row.values.len() as u32,
            self.empty.len() as u32,
        ]);
        out.extend(split(self.seen[0]));
        out.extend(split(self.seen[1]));
        out.extend_from_slice(&self.row.ids);
        out.extend(self.row.values.iter().flat_map(|v| split(v.to_bits())));
        out.extend_from_slice(&self.empty);
    }

    /// The parts packed in `words`, each with its row's index and group;
    /// `columns(index)` gives a row's column count. `None` if they are cut short.
    pub fn unpack(
        mut words: &[u32],
        columns: impl Fn(usize) -> usize,
    ) -> Option<Vec<(usize, usize, Self)>> {
        let join = |w: &[u32]| u64::from(w[0]) | u64::from(w[1]) << 32;
        let mut out = Vec::new();
        while !words.is_empty() {
            let head = words.get(..HEADER)?;
            let (index, group) = (head[0] as usize, head[1] as usize);
            let (ids, values, empty) = (head[2] as usize, head[3] as usize, head[4] as usize);
            let body = words.get(HEADER..HEADER + ids + 2 * values + empty)?;
            let (id_words, rest) = body.split_at(ids);
            let (value_words, empty_words) = rest.split_at(2 * values);
            let row = Row {
                columns: columns(index),
                ids: id_words.to_vec(),
                values: value_words
                    .chunks_exact(2)
                    .map(|w| f64::from_bits(join(w)))
                    .collect(),
                ..Row::default()
            };
            let seen = [join(&head[5..7]), join(&head[7..9])];
            let empty = empty_words.to_vec();
            out.push((index, group, Self { row, seen, empty }));
            words = &words[HEADER + body.len()..];
        }
        Some(out)
    }
}

/// A split shot this rank started, waiting for its groups' parts.
pub(super) struct Pending {
    split: Split,
    key: RowKey,
    tier: usize,
    /// The first hemisphere's items (whole: one process draws every cell).
    whole: Vec<u32>,
    /// Time and CPU seconds spent on it so far (outside exchanges).
    busy: Duration,
    busy_cpu: f64,
}

impl GpuFormFactors<'_> {
    /// The tier the shot of `shooter` over `region` draws in.
    pub(super) fn tier_of(&self, shooter: u32, region: &ShotRegion) -> usize {
        self.tier_at(shooter, region.power)
    }

    /// The tier a shot of `shooter` with unshot power `power` draws in.
    pub(super) fn tier_at(&self, shooter: u32, power: f64) -> usize {
        let polygon = self.mesh.patches[shooter as usize].polygon as usize;
        self.choice
            .tier_for(power, self.mesh.polygons[polygon].emits())
    }

    /// What one group of a split shot of `shooter` over `region` costs, in
    /// hemispheres of the fine tier (every rank alike; a group's hemisphere
    /// ends at its reach, so this is an upper bound).
    pub fn group_cost(&self, shooter: u32, region: &ShotRegion) -> f64 {
        let tier = self.tier_of(shooter, region);
        self.tiers[tier].cells.resolution.cells() as f64
            / self.tiers[0].cells.resolution.cells() as f64
    }

    /// As [`crate::solver::FormFactorSource::form_factors`], except that a
    /// split shot of a hybrid row stops after its first hemisphere: its
    /// groups are then drawn by [`Self::group_part`] (on any rank of a
    /// batched solve) and its row assembled by [`Self::finish_row`]. For a
    /// source of one process (a batched solve's).
    pub fn start_row(
        &mut self,
        shooter: u32,
        region: &ShotRegion,
        out: &mut Vec<Transfer>,
    ) -> Result<Started, RenderError> {
        let start = Instant::now();
        let cpu = parallel::CpuSpan::start(self.comm);
        let Some((key, tier)) = self.fresh_key(shooter, region, out, (start, cpu)) else {
            return Ok(Started::Row);
        };
        let before = self.timings.drawing();
        let (row, exchange) = if self.method == crate::settings::FormFactorMethod::Hybrid {
            let (first, exchange) = self.hybrid_first(shooter, region.centre, tier)?;
            match first {
                First::Whole(row) => (row, exchange),
                First::Split(split) => {
                    let groups = split.groups.len();
                    let busy = self.note_partial(start, before, exchange);
                    self.pending.push(Pending {
                        split,
                        key,
                        tier,
                        whole: self.whole_items.first().cloned().unwrap_or_default(),
                        busy,
                        busy_cpu: cpu.own(self.comm),
                    });
                    return Ok(Started::Split(groups));
                }
            }
        } else {
            self.fresh_row(shooter, region.centre, tier)?
        };
        let clock = super::RowClock::alone(start, cpu, before, exchange);
        self.take_row(key, row, region, out, clock);
        Ok(Started::Row)
    }

    /// Group `group` of the split shot of `shooter` over `region` (which
    /// any rank may have started), drawn here.
    pub fn group_part(
        &mut self,
        shooter: u32,
        region: &ShotRegion,
        group: usize,
    ) -> Result<GroupPart, RenderError> {
        let start = Instant::now();
        let before = self.timings.drawing();
        let tier = self.tier_of(shooter, region);
        let columns = self.mesh.patches[shooter as usize].elements.len();
        let groups = formfactor::split_groups(self.mesh, shooter, columns);
        let Some(g) = groups.get(group) else {
            return Err(RenderError::SplitShot(
                shooter,
                format!("no group {group} of {}", groups.len()),
            ));
        };
        // Without the first hemisphere here, the view is of the drawn cells
        // alone (`view_of`); the assembling rank adds the rest.
        let whole = std::mem::take(&mut self.whole_items);
        let drawn = self.group_row(g, shooter, tier);
        self.whole_items = whole;
        let (row, exchange) = drawn?;
        let empty = self.tiers[tier].cells.empty_runs(&self.items);
        self.note_partial(start, before, exchange);
        Ok(GroupPart {
            row,
            seen: [self.view[0], self.view[1]],
            empty,
        })
    }

    /// The row of the split shot of `shooter` this rank started, from its
    /// groups' `parts` in group order, into `out`.
    pub fn finish_row(
        &mut self,
        shooter: u32,
        region: &ShotRegion,
        parts: &[&GroupPart],
        out: &mut Vec<Transfer>,
    ) -> Result<(), RenderError> {
        let start = Instant::now();
        let cpu = parallel::CpuSpan::start(self.comm);
        let Some(at) = self.pending.iter().position(|p| p.split.shooter == shooter) else {
            return Err(RenderError::SplitShot(shooter, "not started here".into()));
        };
        let Pending {
            mut split,
            key,
            tier,
            whole,
            busy,
            busy_cpu,
        } = self.pending.swap_remove(at);
        if parts.len() != split.groups.len() {
            return Err(RenderError::SplitShot(
                shooter,
                format!("{} parts of {} groups", parts.len(), split.groups.len()),
            ));
        }
        let cells = &self.tiers[tier].cells;
        let mut views = Vec::with_capacity(3 * parts.len());
        for part in parts {
            split.row.merge(&part.row);
            // Beyond its reach a group sees what the shot's centre saw.
            let beyond = cells.view_shares_within(&whole, &part.empty);
            views.extend([
                part.seen[0] + beyond[0],
                part.seen[1] + beyond[1],
                beyond[2],
            ]);
        }
        let (row, exchange) = self.finish_split(split, &views);
        let before = self.timings.drawing();
        let clock = super::RowClock::alone(start, cpu, before, exchange);
        self.take_row(key, row, region, out, clock);
        if let (Some(b), Some(c)) = (self.busy.last_mut(), self.busy_cpu.last_mut()) {
            *b += busy.as_secs_f64();
            *c += busy_cpu;
        }
        Ok(())
    }

    /// Times a piece of a split shot: its summing, and its time outside
    /// exchanges, which it returns.
    fn note_partial(
        &mut self,
        start: Instant,
        drawn_before: Duration,
        exchange: Duration,
    ) -> Duration {
        let total = start.elapsed();
        let drawn = self.timings.drawing() - drawn_before;
        self.timings.exchange += exchange;
        self.timings.sum += total.saturating_sub(exchange + drawn);
        total.saturating_sub(exchange)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn group_parts_travel_exactly() {
        let part = |n: u32, columns: usize| GroupPart {
            row: Row {
                columns,
                ids: (0..n).map(|k| 3 * k + 1).collect(),
                values: (0..n as usize * columns)
                    .map(|k| (k as f64 + 0.1).sqrt() * 1e-7)
                    .collect(),
                ..Row::default()
            },
            seen: [u64::MAX - 5, 1 << 40],
            empty: vec![0, 7, 512, 1024],
        };
        let (a, b) = (part(5, 4), part(0, 2));
        let mut words = Vec::new();
        a.pack(3, 1, &mut words);
        b.pack(9, 0, &mut words);
        let columns = |k: usize| if k == 3 { 4 } else { 2 };
        let got = GroupPart::unpack(&words, columns).expect("unpacks");
        assert_eq!(got, vec![(3, 1, a), (9, 0, b)]);
        // Cut short: refused, not misread.
        assert!(GroupPart::unpack(&words[..words.len() - 1], columns).is_none());
    }
}
