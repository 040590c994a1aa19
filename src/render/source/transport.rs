//! Weak shooters along the ambient term's transport: the shot's row from
//! the transport's ray-sampled shares instead of a hemisphere, each rank
//! making its own elements' part.

use super::*;

impl GpuFormFactors<'_> {
    /// A weak shooter's row along the ambient term's transport: its group's
    /// ray-sampled shares, each spread over the receiving group's elements
    /// by area (F = share * A_j / A_group), the patch shooting its mean
    /// radiosity. The same on every rank (the transport is seeded), and
    /// each rank makes only its own elements' transfers: the update and the
    /// landing skip every other rank's, and a weak shooter's row reaches
    /// thousands of elements, so a whole row on every rank was work every
    /// rank repeated.
    pub(super) fn transport_row(
        &mut self,
        shooter: u32,
        region: &ShotRegion,
        out: &mut Vec<Transfer>,
    ) {
        let mesh = self.mesh;
        let transport = mesh.ambient_transport();
        let g = transport.group_of(shooter);
        let (rank, ranks) = self.transport_ranks;
        let owners = parallel::Owners::new(mesh.patches.len(), ranks);
        out.clear();
        for &(h, share) in transport.row(g) {
            let h = h as usize;
            let area = transport.area_of(h);
            if area <= 0.0 {
                continue;
            }
            let own = transport
                .patches_of(h)
                .iter()
                .filter(|&&p| ranks <= 1 || owners.of(p) == rank);
            for j in own.flat_map(|&p| mesh.patches[p as usize].elements.clone()) {
                // A degenerate element takes nothing (the solver divides
                // by its area). (The packed table: a transport row reaches
                // thousands of elements, a record apiece was a cache miss.)
                let a = self.receivers.area(j);
                if a <= 0.0 {
                    continue;
                }
                let f = share * a / area;
                out.push(Transfer {
                    element: j,
                    form_factor: f,
                    radiosity: region.shoot.map(|s| f * s),
                });
            }
        }
        // Clusters' elements interleave with other clusters'. Each element
        // comes once, so its number orders the row wholly; sorting 8-byte
        // keys (element, position) and gathering once moves less than
        // sorting the 40-byte transfers.
        self.sort_keys.clear();
        self.sort_keys.extend(
            out.iter()
                .enumerate()
                .map(|(k, t)| u64::from(t.element) << 32 | k as u64),
        );
        self.sort_keys.sort_unstable();
        self.sorted.clear();
        self.sorted.extend(
            self.sort_keys
                .iter()
                .map(|&k| out[(k & 0xffff_ffff) as usize]),
        );
        std::mem::swap(out, &mut self.sorted);
        self.last_blocked = transport.back_share(g);
        self.timings.transported += 1;
    }

    /// Times a row that drew nothing (a cache hit or a transport row): all
    /// of it is summing, busy on this rank.
    pub(super) fn note_quick_row(&mut self, start: Instant, cpu: parallel::CpuSpan) {
        let spent = start.elapsed();
        self.timings.sum += spent;
        self.busy.push(spent.as_secs_f64());
        self.busy_cpu.push(cpu.own(self.comm));
    }
}
