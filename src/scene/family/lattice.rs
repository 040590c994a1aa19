//! The family's regular and thin scenes: where visibility sampled at one
//! point of a shooter aliases against the geometry (a lattice of boxes whose
//! gaps are narrower than the boxes, a grid of ceiling panels over shelves)
//! and where a thin thing sits a centimetre or two from a wall (a picture, a
//! skirting board, a shelf board, small objects on a table). Each layer or
//! thing is a node of its own, so a per-node score sees regional errors.

use super::{looking_in, Camera, Gen};
use crate::scene::gltf_write::box_faces;
use glam::Vec3;

impl Gen {
    /// A closed room with a 3-D grid of equal boxes, one node a layer: the
    /// gaps narrower than the boxes, the pitch and the light's size drawn
    /// apart (so the pitch is a multiple of the light's patches or not).
    pub(super) fn lattice(&mut self) -> Camera {
        let n = 3 + (self.rng.next_u64() % 2) as usize;
        let side = self.uniform(0.45, 0.7);
        let gap = side * self.uniform(0.4, 0.8);
        let pitch = side + gap;
        let extent = n as f32 * pitch - gap;
        let floor_gap = if self.rng.next_u64() % 2 == 0 {
            0.0
        } else {
            self.uniform(0.1, 0.4)
        };
        let size = Vec3::new(
            extent + self.uniform(1.6, 2.4),
            floor_gap + extent + self.uniform(1.0, 1.6),
            extent + self.uniform(1.6, 2.4),
        );
        let light = self.uniform(1.2, 2.2);
        let camera = self.room(size, light);
        let origin = Vec3::new(0.5 * (size.x - extent), floor_gap, 0.5 * (size.z - extent));
        for layer in 0..n {
            let mut polygons = Vec::new();
            for i in 0..n {
                for k in 0..n {
                    let lo = origin + Vec3::new(i as f32, layer as f32, k as f32) * pitch;
                    polygons.extend(box_faces(lo, lo + Vec3::splat(side), true));
                }
            }
            let c = self.colour();
            self.node(&format!("layer_{layer}"), polygons, c, [0.0; 3]);
        }
        camera
    }

    /// A room lit by a grid of small ceiling panels (one node), with two
    /// bookcases of shelf boards carrying boxes (a node a shelf).
    pub(super) fn shelves(&mut self) -> Camera {
        let size = Vec3::new(self.uniform(5.0, 6.5), 3.0, self.uniform(5.0, 6.5));
        let c = self.colour();
        self.node("room", box_faces(Vec3::ZERO, size, false), c, [0.0; 3]);
        let (cols, rows) = (3, 2 + (self.rng.next_u64() % 2) as usize);
        let panel = self.uniform(0.3, 0.6);
        let pitch = panel + self.uniform(0.3, 0.9);
        let y = size.y - 0.01;
        let mut panels = Vec::new();
        for i in 0..cols {
            for k in 0..rows {
                let x = 0.5 * size.x + (i as f32 - 0.5 * (cols - 1) as f32) * pitch;
                let z = 0.5 * size.z + (k as f32 - 0.5 * (rows - 1) as f32) * pitch;
                let h = 0.5 * panel;
                panels.push(vec![
                    Vec3::new(x - h, y, z - h),
                    Vec3::new(x + h, y, z - h),
                    Vec3::new(x + h, y, z + h),
                    Vec3::new(x - h, y, z + h),
                ]);
            }
        }
        self.node("panels", panels, [0.8; 3], [20.0, 18.0, 15.0]);
        for case in 0..2 {
            let x0 = 0.5 + case as f32 * 0.5 * size.x;
            self.bookcase(case, Vec3::new(x0, 0.0, 0.02), 0.38 * size.x);
        }
        looking_in(size)
    }

    /// A bookcase against the -z wall from `at`, `width` wide: two sides
    /// and four shelf boards 2 cm thick, boxes on each.
    fn bookcase(&mut self, case: usize, at: Vec3, width: f32) {
        let (depth, height, board) = (0.35, 2.0, 0.02);
        let sides = [
            box_faces(at, at + Vec3::new(board, height, depth), true),
            box_faces(
                at + Vec3::new(width - board, 0.0, 0.0),
                at + Vec3::new(width, height, depth),
                true,
            ),
        ];
        let c = self.colour();
        self.node(&format!("case_{case}_sides"), sides.concat(), c, [0.0; 3]);
        for shelf in 0..4 {
            let y = 0.1 + shelf as f32 * 0.6;
            let lo = at + Vec3::new(board, y, 0.0);
            let mut polygons =
                box_faces(lo, lo + Vec3::new(width - 2.0 * board, board, depth), true);
            let mut x = board + 0.02;
            while x < width - 0.3 {
                let w = self.uniform(0.05, 0.25);
                let h = self.uniform(0.1, 0.4);
                let lo = at + Vec3::new(x, y + board, self.uniform(0.0, 0.1));
                polygons.extend(box_faces(lo, lo + Vec3::new(w, h, 0.2), true));
                x += w + self.uniform(0.0, 0.08);
            }
            let c = self.colour();
            self.node(&format!("case_{case}_shelf_{shelf}"), polygons, c, [0.0; 3]);
        }
    }

    /// Thin things in a room: a picture 1-2 cm off a wall, a skirting board
    /// in the corner of wall and floor, a shelf board on a wall, and a
    /// table with small objects on it (each a node).
    pub(super) fn thin(&mut self) -> Camera {
        let size = Vec3::new(self.uniform(4.0, 6.0), 2.8, self.uniform(4.0, 6.0));
        let light = self.uniform(0.8, 1.4);
        let camera = self.room(size, light);
        self.furnish(size);
        camera
    }

    /// A room's thin things (see [`Gen::thin`]), each a node.
    pub(super) fn furnish(&mut self, size: Vec3) {
        // Along the -z wall (the camera looks at it from +z).
        let off = self.uniform(0.01, 0.02);
        let (w, h) = (self.uniform(0.6, 1.2), self.uniform(0.4, 0.8));
        let lo = Vec3::new(0.5 * size.x - 0.5 * w, 1.2, off);
        let c = self.colour();
        let picture = box_faces(lo, lo + Vec3::new(w, h, 0.015), true);
        self.node("picture", picture, c, [0.0; 3]);
        let skirt = self.uniform(0.06, 0.12);
        let c = self.colour();
        let boards = [
            box_faces(Vec3::ZERO, Vec3::new(size.x, skirt, 0.015), true),
            box_faces(
                Vec3::new(0.0, 0.0, 0.015),
                Vec3::new(0.015, skirt, size.z),
                true,
            ),
        ]
        .concat();
        self.node("skirting", boards, c, [0.0; 3]);
        let y = self.uniform(1.4, 1.9);
        let lo = Vec3::new(size.x - 0.015 - 0.25, y, 0.5 * size.z - 0.6);
        let c = self.colour();
        let shelf = box_faces(lo, lo + Vec3::new(0.25, 0.02, 1.2), true);
        self.node("shelf", shelf, c, [0.0; 3]);
        // A table: a top on four legs, and small objects on it.
        let (tx, tz, top) = (0.5 * size.x - 0.6, 0.5 * size.z - 0.4, 0.72);
        let mut table = box_faces(
            Vec3::new(tx, top, tz),
            Vec3::new(tx + 1.2, top + 0.03, tz + 0.8),
            true,
        );
        for (dx, dz) in [(0.05, 0.05), (1.1, 0.05), (0.05, 0.7), (1.1, 0.7)] {
            let lo = Vec3::new(tx + dx, 0.0, tz + dz);
            table.extend(box_faces(lo, lo + Vec3::new(0.05, top, 0.05), true));
        }
        let c = self.colour();
        self.node("table", table, c, [0.0; 3]);
        let mut objects = Vec::new();
        for k in 0..5 {
            let d = Vec3::new(
                self.uniform(0.05, 0.12),
                self.uniform(0.05, 0.2),
                self.uniform(0.05, 0.12),
            );
            let lo = Vec3::new(
                tx + 0.1 + 0.2 * k as f32,
                top + 0.03,
                tz + self.uniform(0.1, 0.6),
            );
            objects.extend(box_faces(lo, lo + d, true));
        }
        let c = self.colour();
        self.node("objects", objects, c, [0.0; 3]);
    }
}
