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
//! Receivers are refined with their patches (each keeps its element grid).
//! A separate receiver criterion (neighbouring elements differing by more
//! than half the polygon's mean luminance) was tried: it refined 36 polygons
//! of the 64-cube room, raised the node errors and cost 4-10x the time, so
//! it is not used (see the time-to-accuracy notes in the README).
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

/// Per polygon: whether to double its patch grid.
pub fn decide(mesh: &Mesh, patches: &[PatchStats], emitted: f64) -> Vec<bool> {
    mesh.polygons
        .iter()
        .map(|poly| {
            let shooters = patches
                .get(poly.patches.start as usize..poly.patches.end as usize)
                .unwrap_or(&[])
                .iter()
                .any(|p| emitted > 0.0 && p.power * p.penumbra_share() > SHOOTER_TOL * emitted);
            shooters
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formfactor::SHARE_ONE;
    use crate::mesh::MeshSettings;
    use crate::scene::{Polygon, Scene, Subdivision};
    use glam::Vec3;

    fn square() -> Mesh {
        let vertices = vec![
            Vec3::ZERO,
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let scene = Scene {
            polygons: vec![Polygon {
                normal: crate::scene::polygon_normal(&vertices),
                vertices,
                reflectance: [0.5; 3],
                emission: [0.0; 3],
                node: 0,
                subdivision: Some(Subdivision {
                    patches: [2, 2],
                    elements: [2, 2],
                }),
                back_side: false,
                parent: None,
            }],
            nodes: vec!["n".into()],
            ..Default::default()
        };
        Mesh::build(&scene, &MeshSettings::default())
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
        };
        assert_eq!(decide(&mesh, &patches, 1.0), vec![false]);
        // With a 10 % share: 0.01 of the emitted power, refined.
        patches[1].penumbra = [one / 10, one];
        assert_eq!(decide(&mesh, &patches, 1.0), vec![true]);
    }
}
