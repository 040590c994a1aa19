//! Refinement by need: which polygons a coarse solution says to subdivide
//! further. Pure maths over a mesh and per-patch shot statistics; `render` runs the passes (DESIGN.md section 2, ARCHITECTURE.md).
//!
//! # The criterion
//! A render starts from a coarse mesh (`MeshSettings::refine`) and solves it
//! until no patch left to shoot carries [`SHOOTER_TOL`] of the emitted power
//! (the emitters and the bright first bounces: what casts the sharp
//! shadows). Then it doubles the patch grid of every polygon one of whose
//! patches put more than [`SHOOTER_TOL`] of the emitted power onto receivers
//! that its centre sees only partly (power shot x penumbra share), and
//! repeats on the finer mesh. Hybrid form factors take visibility from the
//! shooter's centre, so where a shadow edge crosses a receiver, the
//! shooter's size blurs it into a penumbra that one point cannot see; a
//! smaller shooter narrows that error. In the 64-cube room this picks the
//! light and the ceiling above it and nothing else.
//!
//! Receivers are refined by a second criterion: a polygon one of whose
//! patches holds its light unevenly (the sum over its elements of area
//! times |B - the patch's mean B|, the power one uniform patch in its place
//! would misplace) by more than `receiver_tol` of the emitted power
//! ([`crate::mesh::MeshSettings::receiver_tol`], `--refine-receivers`) gets
//! its patch grid doubled too (each patch keeps its element grid, so its
//! elements halve with it). A light pool on the floor of a room lit through
//! a small opening is the case: no occluder there casts a penumbra, yet its
//! large patches and elements smear the pool's light and the indirect
//! light it sheds (docs/accuracy.md, "Receivers refined by need"). An
//! earlier receiver criterion (neighbouring elements differing by more than
//! half the polygon's mean luminance, whatever the power involved) refined
//! 36 polygons of the 64-cube room and cost 4-10x the time; this one weighs
//! the difference by the power it carries.
//!
//! The criterion reads only quantities that every rank count computes
//! identically (the shooters' powers and fixed-point shares summed over
//! ranks), so the refined mesh does not depend on the rank count.

use crate::mesh::Mesh;

/// A polygon's shooters are halved when one of them put more than this
/// fraction of the emitted power onto partly visible receivers; a pass ends
/// when no shooter left has this much power.
pub const SHOOTER_TOL: f64 = 0.002;

/// What one patch did in a refinement pass, summed over ranks.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PatchStats {
    /// Power it shot (sum over RGB, W).
    pub power: f64,
    /// Visible form factor to partly visible receivers plus the form factor
    /// near receivers lost to occlusion, and the row total plus the latter
    /// (both [`crate::formfactor::SHARE_ONE`] fixed point, from its first uncached shot).
    pub penumbra: [u64; 2],
    /// How unevenly its elements hold their light at the end of the pass
    /// (`Solver::patch_unevenness`), W.
    pub uneven: f64,
}

/// What a pass decides for one polygon.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Decision {
    /// Its shooters cast penumbrae (see [`SHOOTER_TOL`]).
    pub shooter: bool,
    /// Its receivers hold their light unevenly (see the module docs).
    pub receiver: bool,
}

impl Decision {
    /// Whether the polygon's patch grid is doubled.
    pub fn refine(&self) -> bool {
        self.shooter || self.receiver
    }
}

impl PatchStats {
    /// The share of its light that lands where its size would blur a shadow.
    pub fn penumbra_share(&self) -> f64 {
        if self.penumbra[1] == 0 {
            0.0
        } else {
            self.penumbra[0] as f64 / self.penumbra[1] as f64
        }
    }
}

/// Per polygon: whether to double its patch grid, and why (`receiver_tol`:
/// see the module docs; 0 turns the receivers' criterion off).
pub fn decide(
    mesh: &Mesh,
    patches: &[PatchStats],
    emitted: f64,
    receiver_tol: f64,
) -> Vec<Decision> {
    mesh.polygons
        .iter()
        .map(|poly| {
            let own = patches
                .get(poly.patches.start as usize..poly.patches.end as usize)
                .unwrap_or(&[]);
            let lit = emitted > 0.0;
            Decision {
                shooter: own
                    .iter()
                    .any(|p| lit && p.power * p.penumbra_share() > SHOOTER_TOL * emitted),
                receiver: receiver_tol > 0.0
                    && own.iter().any(|p| lit && p.uneven > receiver_tol * emitted),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formfactor::SHARE_ONE;

    const TOL: f64 = crate::mesh::DEFAULT_RECEIVER_TOL;

    fn square() -> Mesh {
        crate::mesh::unit_square(2, 2)
    }

    #[test]
    fn shooters_refine_by_power_times_penumbra_share() {
        let mesh = square();
        let mut patches = vec![PatchStats::default(); mesh.patches.len()];
        let one = SHARE_ONE as u64;
        // 10 % of the emitted power with a 1 % penumbra share: 0.001, kept.
        patches[1] = PatchStats {
            power: 0.1,
            penumbra: [one / 100, one],
            uneven: 0.0,
        };
        assert!(!decide(&mesh, &patches, 1.0, TOL)[0].refine());
        // With a 10 % share: 0.01 of the emitted power, refined.
        patches[1].penumbra = [one / 10, one];
        let d = decide(&mesh, &patches, 1.0, TOL)[0];
        assert!(d.shooter && !d.receiver, "{d:?}");
    }

    #[test]
    fn receivers_refine_by_the_power_they_hold_unevenly() {
        let mesh = square();
        let mut patches = vec![PatchStats::default(); mesh.patches.len()];
        patches[2].uneven = 0.5 * TOL;
        assert!(!decide(&mesh, &patches, 1.0, TOL)[0].refine());
        patches[2].uneven = 2.0 * TOL;
        let d = decide(&mesh, &patches, 1.0, TOL)[0];
        assert!(d.receiver && !d.shooter, "{d:?}");
        // A tolerance of 0 turns the criterion off.
        assert!(!decide(&mesh, &patches, 1.0, 0.0)[0].refine());
    }
}
