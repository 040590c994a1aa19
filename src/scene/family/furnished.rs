//! The family's furnished rooms: no lamp, lit by a sun and a sky through a
//! window in one wall, with a table of small objects, chairs of thin parts,
//! a picture just off a wall, skirting boards and a shelf board (each a node,
//! so a per-node score sees regional errors). Open: light leaves through the
//! window.

use super::{looking_in, Camera, Gen};
use crate::scene::gltf_write::box_faces;
use crate::scene::Light;
use glam::Vec3;

/// The furnished rooms' sun: the direction toward it (through the window
/// in the -x wall, from above) and its irradiance, W/m^2.
pub const SUN: [f64; 4] = [-1.0, 0.9, 0.3, 20.0];
/// The furnished rooms' sky radiance, W sr^-1 m^-2.
pub const SKY: f64 = 1.0;

/// The sun and the sky a furnished room is lit by.
pub fn lights() -> (Light, [f64; 3]) {
    let [x, y, z, e] = SUN;
    let mut sun = crate::scene::parse_sun(&format!("{x},{y},{z},{e}")).expect("a valid sun");
    sun.name = super::CARRIED_SUN.into();
    (sun, [SKY; 3])
}

impl Gen {
    /// A room with a window in its -x wall, furnished (see the module docs).
    pub(super) fn furnished(&mut self) -> Camera {
        let size = Vec3::new(self.uniform(4.0, 6.0), 2.7, self.uniform(4.5, 6.0));
        let (w, h) = (self.uniform(1.0, 1.8), self.uniform(1.0, 1.4));
        let (z0, y0) = (self.uniform(0.8, size.z - w - 1.2), self.uniform(0.8, 1.0));
        let mut walls = box_faces(Vec3::ZERO, size, false);
        let (floor, ceiling) = (walls.remove(2), walls.remove(2));
        // The -x wall (facing +x) around the window.
        walls.remove(0);
        let q = |ya: f32, yb: f32, za: f32, zb: f32| {
            vec![
                Vec3::new(0.0, ya, za),
                Vec3::new(0.0, yb, za),
                Vec3::new(0.0, yb, zb),
                Vec3::new(0.0, ya, zb),
            ]
        };
        walls.extend([
            q(0.0, size.y, 0.0, z0),
            q(0.0, size.y, z0 + w, size.z),
            q(0.0, y0, z0, z0 + w),
            q(y0 + h, size.y, z0, z0 + w),
        ]);
        let c = self.colour();
        self.node("walls", walls, c, [0.0; 3]);
        let c = self.colour();
        self.node("floor", vec![floor], c, [0.0; 3]);
        self.node("ceiling", vec![ceiling], [0.8; 3], [0.0; 3]);
        self.furnish(size);
        for k in 0..2 {
            let at = Vec3::new(0.5 * size.x - 0.5 + 0.7 * k as f32, 0.0, 0.5 * size.z + 0.5);
            self.chair(k, at);
        }
        looking_in(size)
    }

    /// A chair at `at` (its front left foot), facing -z: a seat on four thin
    /// legs and a back of two posts and a rail.
    fn chair(&mut self, k: usize, at: Vec3) {
        let (seat, leg, depth) = (0.45, 0.03, 0.42);
        let mut parts = box_faces(
            at + Vec3::new(0.0, seat, 0.0),
            at + Vec3::new(0.42, seat + 0.03, depth),
            true,
        );
        for (dx, dz) in [
            (0.0, 0.0),
            (0.39, 0.0),
            (0.0, depth - leg),
            (0.39, depth - leg),
        ] {
            let lo = at + Vec3::new(dx, 0.0, dz);
            parts.extend(box_faces(lo, lo + Vec3::new(leg, seat, leg), true));
        }
        for dx in [0.0, 0.39] {
            let lo = at + Vec3::new(dx, seat + 0.03, depth - leg);
            parts.extend(box_faces(lo, lo + Vec3::new(leg, 0.45, leg), true));
        }
        let lo = at + Vec3::new(leg, seat + 0.3, depth - leg);
        parts.extend(box_faces(lo, lo + Vec3::new(0.36, 0.12, leg), true));
        let c = self.colour();
        self.node(&format!("chair_{k}"), parts, c, [0.0; 3]);
    }
}
