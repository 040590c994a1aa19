//! The far receivers of a hybrid shot: patches too small for the
//! hemisphere's cells, which get their visibility by ray, and which
//! patches the cells saw. Part of [`GpuFormFactors`] (its fields are this
//! module's parent's).

use super::GpuFormFactors;
use crate::formfactor;
use crate::mesh::Mesh;
use crate::parallel;
use std::time::Instant;

/// Patches that subtend less than this many of the largest hemisphere cells
/// and that no cell saw get their visibility by ray (see
/// `GpuFormFactors::add_far_receivers`).
pub const FAR_CELLS: f32 = 4.0;

/// Far receivers' scans of at least this many patches use every core, in
/// runs of [`FAR_RUN`] patches.
const PARALLEL_FAR: usize = 16_384;
const FAR_RUN: usize = 4096;

/// One of this rank's patches as the far receivers' scan reads it: every
/// shot tests every patch, and reading these from the patches, polygons
/// and elements was a cache miss apiece (most of the scan's time in big
/// scenes).
#[derive(Clone, Copy)]
pub(super) struct FarPatch {
    centre: glam::Vec3,
    area: f32,
    normal: glam::Vec3,
    patch: u32,
}

impl FarPatch {
    /// Rank `rank`'s patches of `ranks`, in increasing order.
    pub(super) fn owned(mesh: &Mesh, rank: usize, ranks: usize) -> Vec<Self> {
        parallel::Owners::new(mesh.patches.len(), ranks)
            .patches(rank, mesh.patches.len())
            .map(|k| {
                let p = &mesh.patches[k];
                Self {
                    centre: p.centre,
                    area: p.area as f32,
                    normal: mesh.polygons[p.polygon as usize].normal,
                    patch: k as u32,
                }
            })
            .collect()
    }
}

impl GpuFormFactors<'_> {
    /// Receivers too small to cover a hemisphere cell from the shooter (the
    /// far end of a corridor): cell centres miss most of them, and a hybrid
    /// row, which takes visibility from the cells, gave them nothing (the
    /// corridor's far end was 30 % too dark). Each of this rank's patches
    /// that no cell covered, in front of the shooter at `centre`, facing it
    /// and subtending less than [`FAR_CELLS`] of the largest cells, gets its
    /// elements' visibility from rays from `centre` (visible: one visible of
    /// one covered cell): one to its centre, and, when that one is clear and
    /// the patch subtends more than one cell, one to each element (a patch
    /// under a cell takes its centre's answer). Only elements `keep` accepts
    /// of patches whose centres lie `within` of `centre` (a split group's
    /// near receivers) are looked at. Deterministic and per
    /// rank, so the row is the same on any rank count.
    pub(super) fn add_far_receivers(
        &mut self,
        shooter: u32,
        centre: glam::Vec3,
        tier: usize,
        within: f32,
        keep: impl Fn(u32) -> bool + Sync,
    ) {
        let start = Instant::now();
        let mesh = self.mesh;
        let res = self.tiers[tier].cells.resolution;
        // The largest cells are at the horizon: dtheta times dphi.
        let cell = (2.0 * std::f32::consts::PI / res.cols as f32)
            * (std::f32::consts::FRAC_PI_2 / res.rows as f32);
        let sp = &mesh.patches[shooter as usize];
        let n = mesh.polygons[sp.polygon as usize].normal;
        let origin = centre + n * mesh.ray_offset;
        self.mark_seen();
        let before = self.pairs.len();
        let seen = &self.seen;
        // The elements the rays see, in patch order, from a run of patches.
        let scan = |part: &[FarPatch]| -> Vec<u32> {
            let mut found = Vec::new();
            // Most candidates in a cluttered scene are hidden, by the same
            // occluder as the patch before them (see `Bvh::occluded_hinted`).
            let mut hint = None;
            for fp in part {
                let k = fp.patch as usize;
                if k == shooter as usize || seen[k] {
                    continue;
                }
                let d = fp.centre - centre;
                let dist2 = d.length_squared();
                if dist2 > within * within {
                    continue;
                }
                let rn = fp.normal;
                let cos_r = -rn.dot(d);
                if n.dot(d) <= 0.0 || cos_r <= 0.0 {
                    continue;
                }
                let solid_angle = fp.area * cos_r / (dist2 * dist2.sqrt());
                let p = &mesh.patches[k];
                if solid_angle > FAR_CELLS * cell || !p.elements.clone().any(&keep) {
                    continue;
                }
                // One ray to the patch's centre first: most such patches are
                // hidden, and a patch this small hidden at its centre is taken
                // as hidden whole.
                let to = p.centre + rn * mesh.ray_offset - origin;
                let skip = [sp.polygon, p.polygon];
                if mesh
                    .occluders
                    .occluded_hinted(origin, to, 0.0, 1.0, skip, &mut hint)
                {
                    continue;
                }
                let one_cell = solid_angle <= cell;
                for j in p.elements.clone() {
                    let e = &mesh.elements[j as usize];
                    let to = e.centre + rn * mesh.ray_offset - origin;
                    if keep(j)
                        && n.dot(to) > 0.0
                        && (one_cell || !mesh.occluders.occluded(origin, to, 0.0, 1.0, skip))
                    {
                        found.push(j);
                    }
                }
            }
            found
        };
        // Runs of patches on every core, joined in order (the hint only
        // saves time, so the verdicts are the same however it is split).
        let found: Vec<u32> = if self.far_patches.len() < PARALLEL_FAR {
            scan(&self.far_patches)
        } else {
            let runs: Vec<&[FarPatch]> = self.far_patches.chunks(FAR_RUN).collect();
            let mut parts = vec![Vec::new(); runs.len()];
            crate::sampling::in_parallel(&mut parts, |k, part| *part = scan(runs[k]));
            parts.concat()
        };
        for j in found {
            self.pairs.push((j, formfactor::VISIBLE_ONE + 1));
            self.rayed[self.receivers.patch(j) as usize] = true;
        }
        if self.pairs.len() > before {
            // A patch the rays saw takes their verdict alone: the cells
            // it covered (all hidden, or it would have been seen) go, so
            // its elements' visibilities do not depend on whether a
            // hidden polygon was drawn (the occlusion cull) or not.
            let (receivers, rayed) = (&self.receivers, &mut self.rayed);
            let mut index = 0;
            self.pairs.retain(|&(j, _)| {
                index += 1;
                index > before || !rayed[receivers.patch(j) as usize]
            });
            for &(j, _) in &self.pairs {
                rayed[receivers.patch(j) as usize] = false;
            }
            // Two sorted runs (the cells' pairs, then these in patch
            // order): the stable sort finds them and merges in one pass.
            self.pairs.sort_by_key(|p| p.0);
        }
        self.timings.far += start.elapsed();
    }

    /// The receivers of the last hemisphere with a visible cell (or a far
    /// receiver's ray): the work a hybrid row does per receiver, counted
    /// alike whether hidden polygons were drawn or culled.
    pub(super) fn visible_receivers(&self) -> u64 {
        self.pairs
            .iter()
            .filter(|p| formfactor::unpack(p.1).0 > 0)
            .count() as u64
    }

    /// Marks in `self.seen` the patches the last hemisphere's cells saw (a
    /// visible cell, not only covered ones: whether a hidden patch was drawn
    /// at all depends on the occlusion cull, and must not change its rays).
    fn mark_seen(&mut self) {
        self.seen.iter_mut().for_each(|s| *s = false);
        for &(j, x) in &self.pairs {
            if formfactor::unpack(x).0 > 0 {
                self.seen[self.receivers.patch(j) as usize] = true;
            }
        }
    }
}
