//! Batched shots (`--batch K`): the K strongest patches shoot from one
//! state; each rank draws the rows the deal gives it, split shots' groups
//! are dealt over every rank in a second round, and every row travels to
//! its elements' owners in one all-to-all a batch, 36 bytes a transfer (12
//! where the row is uniform: the owner makes the rest again from the
//! batch's regions).

use super::*;

/// A batched step's buffers: per row this rank's own transfers, per rank
/// the words sent to it, and the words received from every rank.
#[derive(Default)]
pub(super) struct BatchBuffers {
    pub(super) rows: Vec<Vec<Transfer>>,
    pub(super) outgoing: Vec<Vec<u32>>,
    pub(super) incoming: Vec<u32>,
}

/// One batch as its rounds fill it: its shooters and their regions, per
/// row what this rank knows of it, and the buffers its rows travel in.
struct Batch {
    chosen: Vec<Candidate>,
    regions: Vec<ShotRegion>,
    /// Per row: its record's place in `stats.rows` (`usize::MAX`: none),
    /// its split shot's groups, and whether this rank drew it.
    record_of: Vec<usize>,
    groups: Vec<u32>,
    drew: Vec<bool>,
    /// Per row this rank's own transfers, per rank the words sent to it,
    /// the words received, and per row its sums.
    rows: Vec<Vec<Transfer>>,
    outgoing: Vec<Vec<u32>>,
    incoming: Vec<u32>,
    sums: Vec<f64>,
}

impl Batch {
    /// A batch of `chosen` shooting `regions` on `ranks` ranks, in the
    /// buffers `kept` from the last one.
    fn new(
        chosen: Vec<Candidate>,
        regions: Vec<ShotRegion>,
        ranks: usize,
        kept: BatchBuffers,
    ) -> Self {
        let BatchBuffers {
            mut rows,
            mut outgoing,
            incoming,
        } = kept;
        let n = chosen.len();
        rows.resize_with(n, Vec::new);
        outgoing.resize_with(ranks, Vec::new);
        rows.iter_mut().for_each(Vec::clear);
        outgoing.iter_mut().for_each(Vec::clear);
        Self {
            chosen,
            regions,
            record_of: vec![usize::MAX; n],
            groups: vec![0; n],
            drew: vec![false; n],
            rows,
            outgoing,
            incoming,
            sums: vec![0.0; n * ROW_SUMS],
        }
    }
}

impl<'m> ShotLoop<'m> {
    /// One step of a batched loop, after the vote: the batch's shooters,
    /// their rows (each from the rank whose turn it is), and their landing.
    pub(super) fn step_batch<'s>(
        &mut self,
        source: &mut GpuFormFactors,
        solver: &mut Solver<'s>,
        hooks: &mut dyn LoopHooks<'s>,
        (shot_start, unshot_fraction): (Instant, f64),
    ) -> Result<Step, RenderError> {
        let room = self.stop.max_shots.saturating_sub(solver.shots()) as usize;
        let batch = self.batch.min(room.max(1));
        let chosen = self.choose(source, solver, batch);
        self.stats.select += shot_start.elapsed();
        if chosen.is_empty() {
            return Ok(Step::Stopped(Stopped::Floor));
        }
        // A weak shooter along the transport shoots for its group (which
        // empties other patches' stores): it goes alone, as in a loop of
        // one shot a step, every rank making its own elements' part of the
        // (cheap) row (the source's transport ranks are the run's), its
        // landing summed at the next vote.
        if chosen.len() == 1 && source.by_transport(chosen[0].power) {
            let best = chosen[0];
            let mut region = self.region(solver, &best);
            self.join_group(solver, &best, &mut region);
            let shot = self.shoot(source, solver, (&best, &region), None)?;
            self.stats.shot_times.push(shot_start.elapsed());
            hooks.after_shot(solver, unshot_fraction);
            return Ok(Step::Shot(shot));
        }
        let regions: Vec<ShotRegion> = chosen.iter().map(|c| self.region(solver, c)).collect();
        let kept = std::mem::take(&mut self.kept);
        let mut b = Batch::new(chosen, regions, self.comm.size(), kept);
        self.first_round(source, solver, &mut b)?;
        self.split_round(source, solver, &mut b)?;
        let t = Instant::now();
        let cpu = crate::parallel::CpuSpan::start(self.comm);
        let (starts, all_sums) = self.exchange_rows(&mut b);
        source.timings.exchange += t.elapsed();
        let parts = starts.windows(2).filter_map(|w| b.incoming.get(w[0]..w[1]));
        unpack_rows(parts, &mut b.rows, &b.regions);
        let landing_start = Instant::now();
        // Each shot's sums come from the one rank that drew it; the others
        // add exact zeros.
        let mut totals = vec![0.0; b.sums.len()];
        for part in all_sums.chunks_exact(b.sums.len().max(1)) {
            for (t, x) in totals.iter_mut().zip(part) {
                *t += x;
            }
        }
        let last = self.land_batch(solver, &b, &totals);
        self.stats.update += landing_start.elapsed();
        if let Some(busy) = source.busy_cpu.last_mut() {
            *busy += cpu.own(self.comm);
        }
        let n = b.chosen.len();
        let per_shot = shot_start.elapsed() / n as u32;
        self.stats
            .shot_times
            .extend(std::iter::repeat_n(per_shot, n));
        hooks.after_shot(solver, unshot_fraction);
        self.kept = BatchBuffers {
            rows: b.rows,
            outgoing: b.outgoing,
            incoming: b.incoming,
        };
        Ok(last.map_or(Step::Stopped(Stopped::Floor), Step::Shot))
    }

    /// A batch's first round: which rank draws each row (a cached row its
    /// cache's rank, one of the dearest rows each rank, the rest whichever
    /// rank comes free first: only time depends on it), and this rank's
    /// rows drawn, each sent in pieces to the owners of its elements (a
    /// split shot only started: its groups are the second round's).
    fn first_round(
        &mut self,
        source: &mut GpuFormFactors,
        solver: &Solver,
        b: &mut Batch,
    ) -> Result<(), RenderError> {
        let (rank, ranks) = (self.comm.rank(), self.comm.size());
        let n = b.chosen.len();
        let costs: Vec<f64> = b
            .chosen
            .iter()
            .zip(&b.regions)
            .map(|(c, r)| source.row_cost(c.patch, r))
            .collect();
        let costs = if ranks > 1 {
            self.comm.all_gather_f64(&costs)
        } else {
            costs
        };
        let deal = crate::parallel::assign_rows(&costs, ranks);
        let batch_start = solver.shots();
        let recorded = batch_start < MAX_ROW_RECORDS;
        for k in (0..n).filter(|&k| deal[k] == rank) {
            let (patch, region) = (b.chosen[k].patch, &b.regions[k]);
            b.drew[k] = true;
            let cpu = crate::parallel::process_cpu_seconds();
            match source.start_row(patch, region, &mut self.ff)? {
                Started::Row => self.send_row(solver, source, k, b),
                Started::Split(groups) => b.groups[k] = groups as u32,
            }
            let cpu_seconds = crate::parallel::process_cpu_seconds() - cpu;
            self.stats.rows_cpu_seconds += cpu_seconds;
            if recorded {
                b.record_of[k] = self.stats.rows.len();
                self.stats.rows.push(RowRecord {
                    batch_start,
                    index: k as u32,
                    round: 0,
                    cost: costs.get(rank * n + k).copied().unwrap_or(1.0),
                    cpu_seconds,
                });
            }
        }
        // A shooter's penumbra is its last row's, which another rank may
        // have drawn: the passes sum every rank's (see `refined_mesh`).
        for (c, _) in b.chosen.iter().zip(&b.drew).filter(|(_, &d)| !d) {
            source.forget_penumbra(c.patch);
        }
        Ok(())
    }

    /// Sends every rank its pieces of the batch's rows (unpacked into
    /// `b.rows` after the timed exchange) and gathers every row's sums.
    fn exchange_rows(&self, b: &mut Batch) -> (Vec<usize>, Vec<f64>) {
        let starts = self.comm.all_to_all_u32_into(&b.outgoing, &mut b.incoming);
        (starts, self.comm.all_gather_f64(&b.sums))
    }

    /// Lands the batch's rows in its order. Every shooter gives up its
    /// store before any shot lands, so light one of them lands on another
    /// stays for a later batch. Returns the last shot.
    fn land_batch(&mut self, solver: &mut Solver, b: &Batch, totals: &[f64]) -> Option<Shot> {
        let shares: Vec<[f64; 3]> = b
            .chosen
            .iter()
            .zip(&b.regions)
            .map(|(c, r)| solver.take_shooter(c, r))
            .collect();
        let mut last = None;
        for (k, (c, region)) in b.chosen.iter().zip(&b.regions).enumerate() {
            let mut shot = solver.land(c, region, &b.rows[k], shares[k]);
            let s = &totals[k * ROW_SUMS..(k + 1) * ROW_SUMS];
            shot.form_factor_sum = s[3];
            self.after_landing(solver, c, shot, [s[0], s[1], s[2], s[3]]);
            last = Some(shot);
        }
        last
    }

    /// Row `k` of a batch, just made in `self.ff`: its sums noted and its
    /// transfers packed for their owners.
    fn send_row(&self, solver: &Solver, source: &GpuFormFactors, k: usize, b: &mut Batch) {
        let (patch, shoot) = (b.chosen[k].patch, b.regions[k].shoot);
        let s = row_sums(solver, patch, &self.ff, source.last_blocked());
        b.sums[k * ROW_SUMS..(k + 1) * ROW_SUMS].copy_from_slice(&s);
        pack_row(
            solver,
            (k, self.comm.rank(), shoot),
            &self.ff,
            &mut b.outgoing,
            &mut b.rows[k],
        );
    }

    /// Every rank's split shots' group counts and which rank drew each row:
    /// a row's drawer tells its groups plus one, the others 0 (which rank
    /// drew a row is learnt here).
    fn drawers(&self, b: &Batch) -> (Vec<u32>, Vec<usize>) {
        let ranks = self.comm.size();
        if ranks == 1 {
            return (b.groups.clone(), vec![0; b.groups.len()]);
        }
        let marks: Vec<u32> = b
            .groups
            .iter()
            .zip(&b.drew)
            .map(|(&g, &d)| if d { g + 1 } else { 0 })
            .collect();
        let lengths = vec![marks.len(); ranks];
        let mut all = vec![0u32; marks.len()];
        let mut drawer = vec![0usize; marks.len()];
        for (r, part) in self
            .comm
            .all_gather_u32(&marks, Some(&lengths))
            .into_iter()
            .enumerate()
        {
            for (k, m) in part.into_iter().enumerate() {
                if m > 0 {
                    all[k] = m - 1;
                    drawer[k] = r;
                }
            }
        }
        (all, drawer)
    }

    /// A batch's second round: the groups of its split shots, dealt over
    /// every rank as work of their own, sent to the rows' drawers, who
    /// assemble the rows (in group order: the bits of a shot drawn whole)
    /// and pack them as the first round's.
    fn split_round(
        &mut self,
        source: &mut GpuFormFactors,
        solver: &Solver,
        b: &mut Batch,
    ) -> Result<(), RenderError> {
        let ranks = self.comm.size();
        let (groups, drawer) = self.drawers(b);
        let units: Vec<(usize, usize)> = groups
            .iter()
            .enumerate()
            .flat_map(|(k, &n)| (0..n as usize).map(move |g| (k, g)))
            .collect();
        if units.is_empty() {
            return Ok(());
        }
        let batch_start = solver.shots();
        // Every rank weighs a group alike.
        let weights: Vec<f64> = units
            .iter()
            .map(|&(k, _)| source.group_cost(b.chosen[k].patch, &b.regions[k]))
            .collect();
        let all_weights: Vec<f64> = (0..ranks).flat_map(|_| weights.iter().copied()).collect();
        let deal = crate::parallel::assign_rows(&all_weights, ranks);
        let mut parts_out = vec![Vec::new(); ranks];
        let rank = self.comm.rank();
        for u in (0..units.len()).filter(|&u| deal[u] == rank) {
            let (k, g) = units[u];
            let cpu = crate::parallel::process_cpu_seconds();
            let part = source.group_part(b.chosen[k].patch, &b.regions[k], g)?;
            part.pack(k, g, &mut parts_out[drawer[k]]);
            let cpu_seconds = crate::parallel::process_cpu_seconds() - cpu;
            self.stats.rows_cpu_seconds += cpu_seconds;
            if batch_start < MAX_ROW_RECORDS {
                self.stats.rows.push(RowRecord {
                    batch_start,
                    index: u as u32,
                    round: 1,
                    cost: weights[u],
                    cpu_seconds,
                });
            }
        }
        let t = Instant::now();
        let incoming = if ranks > 1 {
            self.comm.all_to_all_u32(&parts_out)
        } else {
            parts_out
        };
        source.timings.exchange += t.elapsed();
        let parts = self.group_parts(&b.chosen, &incoming)?;
        self.assemble(source, solver, b, (&groups, &drawer), parts)
    }

    /// The groups' parts received, per row, with their group numbers.
    fn group_parts(
        &self,
        chosen: &[Candidate],
        incoming: &[Vec<u32>],
    ) -> Result<Vec<Vec<(usize, GroupPart)>>, RenderError> {
        let columns = |k: usize| {
            chosen
                .get(k)
                .map_or(0, |c| self.mesh.patches[c.patch as usize].elements.len())
        };
        let mut parts: Vec<Vec<(usize, GroupPart)>> = vec![Vec::new(); chosen.len()];
        for words in incoming {
            let unpacked = GroupPart::unpack(words, columns).ok_or_else(|| {
                RenderError::SplitShot(u32::MAX, "a part cut short in transit".into())
            })?;
            for (k, g, part) in unpacked {
                if let Some(p) = parts.get_mut(k) {
                    p.push((g, part));
                }
            }
        }
        Ok(parts)
    }

    /// The split rows this rank drew, assembled from their groups' parts
    /// in group order and sent as the first round's rows.
    fn assemble(
        &mut self,
        source: &mut GpuFormFactors,
        solver: &Solver,
        b: &mut Batch,
        (groups, drawer): (&[u32], &[usize]),
        parts: Vec<Vec<(usize, GroupPart)>>,
    ) -> Result<(), RenderError> {
        let rank = self.comm.rank();
        for (k, mut mine) in parts.into_iter().enumerate() {
            if groups[k] == 0 || drawer[k] != rank {
                continue;
            }
            let cpu = crate::parallel::process_cpu_seconds();
            let (patch, region) = (b.chosen[k].patch, &b.regions[k]);
            mine.sort_by_key(|p| p.0);
            let in_order: Vec<&GroupPart> = mine.iter().map(|p| &p.1).collect();
            source.finish_row(patch, region, &in_order, &mut self.ff)?;
            self.send_row(solver, source, k, b);
            let cpu_seconds = crate::parallel::process_cpu_seconds() - cpu;
            self.stats.rows_cpu_seconds += cpu_seconds;
            if let Some(r) = b.record_of.get(k).and_then(|&i| self.stats.rows.get_mut(i)) {
                r.cpu_seconds += cpu_seconds;
            }
        }
        Ok(())
    }
}

/// A whole row's sums a batched shot's energy needs: what it landed and
/// delivered ([`landing`]), the share that met back faces, and the sum of
/// its form factors.
pub(super) const ROW_SUMS: usize = 4;

pub(super) fn row_sums(
    solver: &Solver,
    shooter: u32,
    ff: &[Transfer],
    blocked: f64,
) -> [f64; ROW_SUMS] {
    let (landed, delivered) = landing(solver, shooter, ff.iter());
    let sum = ff.iter().map(|t| t.form_factor).sum();
    [landed as f64, delivered as f64, blocked, sum]
}

/// Words a transfer takes in a batch's exchange: its element, then the
/// form factor's and each channel's radiosity's f64 bits, two words each.
pub(super) const TRANSFER_WORDS: usize = 9;

/// Words a transfer of a uniform shot takes: its element and the form
/// factor's bits. Its radiosities are F times what the patch shoots, which
/// every rank knows (the batch's regions), so the owner makes them again,
/// to the same bits.
pub(super) const UNIFORM_WORDS: usize = 3;

/// A row's header bit saying its transfers travel as [`UNIFORM_WORDS`].
const UNIFORM_ROW: u32 = 1 << 31;

/// Appends `x`'s bits as two words, low first.
pub(super) fn push_bits(out: &mut Vec<u32>, x: f64) {
    let b = x.to_bits();
    out.push(b as u32);
    out.push((b >> 32) as u32);
}

/// The f64 whose bits [`push_bits`] wrote at `w[0..2]`.
pub(super) fn from_words(w: &[u32]) -> f64 {
    f64::from_bits(u64::from(w[0]) | u64::from(w[1]) << 32)
}

/// What a uniform shot of `shoot` sends a receiver of form factor `f`.
pub(super) fn uniform(f: f64, shoot: [f64; 3]) -> [f64; 3] {
    shoot.map(|s| f * s)
}

/// Splits shot `k`'s row, computed on rank `rank`, between its elements'
/// owners: this rank's transfers to `own`, the others' appended to their
/// words as the shot's index and its transfer count, then
/// [`TRANSFER_WORDS`] words a transfer (36 bytes: the element once, not
/// once per value), or [`UNIFORM_WORDS`] (12 bytes, marked by
/// [`UNIFORM_ROW`]) when every transfer's radiosities are, bit for bit,
/// its form factor times `shoot` (a patch shooting uniformly).
pub(super) fn pack_row(
    solver: &Solver,
    (k, rank, shoot): (usize, usize, [f64; 3]),
    ff: &[Transfer],
    outgoing: &mut [Vec<u32>],
    own: &mut Vec<Transfer>,
) {
    let bits = |r: [f64; 3]| r.map(f64::to_bits);
    let compact = ff
        .iter()
        .all(|t| bits(t.radiosity) == bits(uniform(t.form_factor, shoot)));
    let (mark, words) = if compact {
        (UNIFORM_ROW, UNIFORM_WORDS)
    } else {
        (0, TRANSFER_WORDS)
    };
    let starts: Vec<usize> = outgoing.iter().map(Vec::len).collect();
    for (r, out) in outgoing.iter_mut().enumerate() {
        if r != rank {
            out.extend([k as u32 | mark, 0]);
        }
    }
    for t in ff {
        let r = solver.element_rank(t.element);
        if r == rank {
            own.push(*t);
            continue;
        }
        let out = &mut outgoing[r];
        out.push(t.element);
        push_bits(out, t.form_factor);
        if !compact {
            for c in t.radiosity {
                push_bits(out, c);
            }
        }
    }
    for (r, (out, start)) in outgoing.iter_mut().zip(starts).enumerate() {
        if r != rank {
            out[start + 1] = ((out.len() - start - 2) / words) as u32;
        }
    }
}

/// Adds the rows [`pack_row`] sent this rank to `rows`, by shot (each in
/// its row's order), from every rank's words; `regions[k]` is how shot k
/// shoots.
pub(super) fn unpack_rows<'w>(
    incoming: impl Iterator<Item = &'w [u32]>,
    rows: &mut [Vec<Transfer>],
    regions: &[ShotRegion],
) {
    for words in incoming {
        let mut at = 0;
        while let [head, count, ..] = words[at..] {
            let (k, count) = ((head & !UNIFORM_ROW) as usize, count as usize);
            let compact = head & UNIFORM_ROW != 0;
            let size = if compact {
                UNIFORM_WORDS
            } else {
                TRANSFER_WORDS
            };
            at += 2;
            let Some(body) = words.get(at..at + size * count) else {
                break;
            };
            let (Some(row), Some(region)) = (rows.get_mut(k), regions.get(k)) else {
                break;
            };
            row.extend(body.chunks_exact(size).map(|t| {
                let form_factor = from_words(&t[1..3]);
                Transfer {
                    element: t[0],
                    form_factor,
                    radiosity: if compact {
                        uniform(form_factor, region.shoot)
                    } else {
                        [3, 5, 7].map(|c| from_words(&t[c..c + 2]))
                    },
                }
            }));
            at += size * count;
        }
    }
}
