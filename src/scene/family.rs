//! A seeded family of test scenes of the kinds users make, that no default
//! was tuned on: closed rooms with boxes of random sizes, boxes resting on
//! the floor and stacked on one another (contact), a thin slab near a wall
//! (near field), an L-shaped room, a long corridor lit at one end (far
//! field), a room lit through a small opening, a room of many small
//! objects, (`lattice`) a lattice of boxes, shelves under a grid of
//! panels and thin things against walls, and (`furnished`) furnished rooms
//! lit by a sun and a sky through a window. All but the furnished rooms are
//! closed (no light leaves them), so energy must balance; none carries a
//! subdivision of its own (the defaults mesh it).
//! Named `family-KIND-SEED`, e.g. `family-stacked-3`.

mod furnished;
mod lattice;

use super::gltf_write::box_faces;
use super::gltf_write::{write_gltf, GltfSurface};
use crate::rng::Rng;
use glam::{Quat, Vec3};

/// The kinds of scene in the family.
pub const KINDS: [&str; 12] = [
    "boxes",
    "floor",
    "stacked",
    "slab",
    "l-room",
    "corridor",
    "opening",
    "many",
    "lattice",
    "shelves",
    "thin",
    "furnished",
];

/// The name of the sun a generated room carries (a sky map replaces it).
pub const CARRIED_SUN: &str = "window sun";

/// The sun and sky `family-KIND-SEED` is lit by beside its own emitters
/// (`furnished` rooms: through their window), if any.
pub fn family_lights(name: &str) -> Option<(super::Light, [f64; 3])> {
    name.strip_prefix("family-furnished-")?
        .parse::<u64>()
        .ok()
        .map(|_| furnished::lights())
}

/// The glTF text of `family-KIND-SEED`, or `None` when `name` is not one.
pub fn family_gltf(name: &str) -> Option<String> {
    let rest = name.strip_prefix("family-")?;
    let (kind, seed) = rest.rsplit_once('-')?;
    let seed: u64 = seed.parse().ok()?;
    let mut g = Gen {
        rng: Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x00fa_317e),
        surfaces: Vec::new(),
    };
    let camera = match kind {
        "boxes" => g.boxes(false),
        "floor" => g.boxes(true),
        "stacked" => g.stacked(),
        "slab" => g.slab(),
        "l-room" => g.l_room(),
        "corridor" => g.corridor(),
        "opening" => g.opening(),
        "many" => g.many(),
        "lattice" => g.lattice(),
        "shelves" => g.shelves(),
        "thin" => g.thin(),
        "furnished" => g.furnished(),
        _ => return None,
    };
    Some(write_gltf(&g.surfaces, Some(camera)))
}

type Camera = (Vec3, Quat, f32, f32);

struct Gen {
    rng: Rng,
    surfaces: Vec<GltfSurface>,
}

impl Gen {
    /// A uniform number in [lo, hi).
    fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * (self.rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// A random, not too dark, not too bright reflectance.
    fn colour(&mut self) -> [f32; 3] {
        [0; 3].map(|_| self.uniform(0.2, 0.85))
    }

    fn node(
        &mut self,
        name: &str,
        polygons: Vec<Vec<Vec3>>,
        reflectance: [f32; 3],
        emission: [f32; 3],
    ) {
        self.surfaces.push(GltfSurface {
            name: name.into(),
            polygons,
            reflectance,
            emission,
            double_sided: false,
            subdivision: None,
        });
    }

    /// A room `size` from the origin, its faces inward, and a light of
    /// `light` x `light` metres 1 cm under the middle of its ceiling.
    fn room(&mut self, size: Vec3, light: f32) -> Camera {
        let c = self.colour();
        self.node("room", box_faces(Vec3::ZERO, size, false), c, [0.0; 3]);
        let (x, z, y) = (0.5 * size.x, 0.5 * size.z, size.y - 0.01);
        let h = 0.5 * light;
        let quad = vec![
            Vec3::new(x - h, y, z - h),
            Vec3::new(x + h, y, z - h),
            Vec3::new(x + h, y, z + h),
            Vec3::new(x - h, y, z + h),
        ];
        self.node("light", vec![quad], [0.8; 3], [12.0, 11.0, 9.0]);
        looking_in(size)
    }

    /// A closed room with boxes of random sizes, floating or resting on the floor.
    fn boxes(&mut self, on_floor: bool) -> Camera {
        let size = Vec3::new(self.uniform(4.0, 7.0), 3.0, self.uniform(4.0, 7.0));
        let camera = self.room(size, 1.0);
        for k in 0..6 {
            let d = Vec3::new(
                self.uniform(0.3, 1.2),
                self.uniform(0.3, 1.4),
                self.uniform(0.3, 1.2),
            );
            let x = self.uniform(0.2, size.x - d.x - 0.2);
            let z = self.uniform(0.2, size.z - d.z - 0.2);
            let y = if on_floor {
                0.0
            } else {
                self.uniform(0.2, 1.2)
            };
            let lo = Vec3::new(x, y, z);
            let c = self.colour();
            self.node(
                &format!("box_{k}"),
                box_faces(lo, lo + d, true),
                c,
                [0.0; 3],
            );
        }
        camera
    }

    /// Boxes stacked on the floor and on each other, and side by side,
    /// touching.
    fn stacked(&mut self) -> Camera {
        let size = Vec3::new(6.0, 3.0, 6.0);
        let camera = self.room(size, 1.2);
        for pile in 0..3 {
            let (mut y, x0, z0) = (0.0, 0.8 + 1.7 * pile as f32, self.uniform(1.0, 3.5));
            for level in 0..3 {
                let d = Vec3::new(
                    self.uniform(0.5, 1.0),
                    self.uniform(0.3, 0.6),
                    self.uniform(0.5, 1.0),
                );
                let lo = Vec3::new(x0, y, z0);
                let c = self.colour();
                let name = format!("pile_{pile}_{level}");
                self.node(&name, box_faces(lo, lo + d, true), c, [0.0; 3]);
                // A neighbour touching this box's +x face on the floor.
                if level == 0 {
                    let lo = Vec3::new(x0 + d.x, 0.0, z0);
                    let n = Vec3::new(0.3, self.uniform(0.2, 0.5), 0.4);
                    let c = self.colour();
                    self.node(
                        &format!("side_{pile}"),
                        box_faces(lo, lo + n, true),
                        c,
                        [0.0; 3],
                    );
                }
                y += d.y;
            }
        }
        camera
    }

    /// A thin slab parallel to a wall, a few centimetres from it.
    fn slab(&mut self) -> Camera {
        let size = Vec3::new(5.0, 3.0, 5.0);
        let camera = self.room(size, 1.0);
        let gap = self.uniform(0.02, 0.08);
        let lo = Vec3::new(1.0, 0.5, gap);
        let hi = Vec3::new(4.0, 2.5, gap + 0.02);
        let c = self.colour();
        self.node("slab", box_faces(lo, hi, true), c, [0.0; 3]);
        camera
    }

    /// An L-shaped room: a 6 x 4 m wing and a 3 x 4 m wing off it.
    fn l_room(&mut self) -> Camera {
        let h = 3.0;
        let (a, b) = (self.uniform(5.0, 7.0), self.uniform(3.0, 5.0));
        let (c, d) = (self.uniform(2.0, 3.5), self.uniform(3.0, 5.0));
        let p = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
        // Floor and ceiling as two rectangles each (facing up and down).
        let floor = vec![
            vec![
                p(0.0, 0.0, 0.0),
                p(0.0, 0.0, b),
                p(a, 0.0, b),
                p(a, 0.0, 0.0),
            ],
            vec![
                p(0.0, 0.0, b),
                p(0.0, 0.0, b + d),
                p(c, 0.0, b + d),
                p(c, 0.0, b),
            ],
        ];
        let ceiling = floor
            .iter()
            .map(|q| q.iter().rev().map(|v| p(v.x, h, v.z)).collect())
            .collect();
        // The outline counter-clockwise seen from above: walls face inward.
        let outline = [
            (0.0, 0.0),
            (a, 0.0),
            (a, b),
            (c, b),
            (c, b + d),
            (0.0, b + d),
        ];
        let walls = (0..outline.len())
            .map(|k| {
                let (x0, z0) = outline[k];
                let (x1, z1) = outline[(k + 1) % outline.len()];
                vec![p(x0, 0.0, z0), p(x1, 0.0, z1), p(x1, h, z1), p(x0, h, z0)]
            })
            .collect();
        let (wall, fl) = (self.colour(), self.colour());
        self.node("floor", floor, fl, [0.0; 3]);
        self.node("ceiling", ceiling, [0.8; 3], [0.0; 3]);
        self.node("walls", walls, wall, [0.0; 3]);
        let (x, z) = (0.5 * c, b + 0.5 * d);
        let l = 0.5;
        let light = vec![vec![
            p(x - l, h - 0.01, z - l),
            p(x + l, h - 0.01, z - l),
            p(x + l, h - 0.01, z + l),
            p(x - l, h - 0.01, z + l),
        ]];
        self.node("light", light, [0.8; 3], [12.0, 11.0, 9.0]);
        looking_in(Vec3::new(a, h, b))
    }

    /// A long corridor lit by a panel on one end wall.
    fn corridor(&mut self) -> Camera {
        let size = Vec3::new(self.uniform(15.0, 25.0), 2.5, 2.0);
        let c = self.colour();
        self.node("corridor", box_faces(Vec3::ZERO, size, false), c, [0.0; 3]);
        let x = 0.01;
        let panel = vec![vec![
            Vec3::new(x, 0.5, 0.5),
            Vec3::new(x, 2.0, 0.5),
            Vec3::new(x, 2.0, 1.5),
            Vec3::new(x, 0.5, 1.5),
        ]];
        self.node("light", panel, [0.8; 3], [12.0, 11.0, 9.0]);
        (
            Vec3::new(size.x - 0.3, 1.3, 1.0),
            Quat::from_rotation_y(std::f32::consts::FRAC_PI_2),
            1.0,
            1.5,
        )
    }

    /// A room inside a closed hall, lit only through a small opening in one
    /// of its walls (the walls have two sides, back to back).
    fn opening(&mut self) -> Camera {
        let hall = Vec3::new(10.0, 4.0, 10.0);
        let c = self.colour();
        self.node("hall", box_faces(Vec3::ZERO, hall, false), c, [0.0; 3]);
        let light = vec![vec![
            Vec3::new(4.0, 3.99, 0.5),
            Vec3::new(6.0, 3.99, 0.5),
            Vec3::new(6.0, 3.99, 1.5),
            Vec3::new(4.0, 3.99, 1.5),
        ]];
        self.node("light", light, [0.8; 3], [12.0, 11.0, 9.0]);
        // The inner room: x 2..8, y 0..3, z 3..9; its -z wall has a hole.
        let (lo, hi) = (Vec3::new(2.0, 0.0, 3.0), Vec3::new(8.0, 3.0, 9.0));
        let s = self.uniform(0.4, 0.8);
        let (hx, hy) = (5.0, 1.5);
        let mut outer = box_faces(lo, hi, true);
        let mut inner = box_faces(lo, hi, false);
        // Faces: -x, +x, -y, +y, -z, +z; the floor (-y) is the hall's.
        for faces in [&mut outer, &mut inner] {
            faces.remove(4);
            faces.remove(2);
        }
        let z = lo.z;
        let q = |x0: f32, x1: f32, y0: f32, y1: f32| {
            vec![
                Vec3::new(x0, y0, z),
                Vec3::new(x0, y1, z),
                Vec3::new(x1, y1, z),
                Vec3::new(x1, y0, z),
            ]
        };
        let pieces = [
            q(lo.x, hx - s, lo.y, hi.y),
            q(hx + s, hi.x, lo.y, hi.y),
            q(hx - s, hx + s, lo.y, hy - s),
            q(hx - s, hx + s, hy + s, hi.y),
        ];
        for piece in pieces {
            // Facing -z (outside) as drawn; the inside face reversed.
            let mut back = piece.clone();
            back.reverse();
            outer.push(piece);
            inner.push(back);
        }
        let (co, ci) = (self.colour(), self.colour());
        self.node("room_outside", outer, co, [0.0; 3]);
        self.node("room_inside", inner, ci, [0.0; 3]);
        (Vec3::new(5.0, 1.6, 8.7), Quat::IDENTITY, 1.1, 1.4)
    }

    /// A room of many small objects, on the floor and floating.
    fn many(&mut self) -> Camera {
        let size = Vec3::new(6.0, 3.0, 6.0);
        let camera = self.room(size, 1.0);
        let mut polygons = Vec::new();
        for k in 0..60 {
            let d = Vec3::splat(self.uniform(0.08, 0.3));
            let x = self.uniform(0.2, size.x - 0.5);
            let z = self.uniform(0.2, size.z - 0.5);
            let y = if k % 2 == 0 {
                0.0
            } else {
                self.uniform(0.3, 2.0)
            };
            let lo = Vec3::new(x, y, z);
            polygons.extend(box_faces(lo, lo + d, true));
        }
        let c = self.colour();
        self.node("objects", polygons, c, [0.0; 3]);
        camera
    }
}

/// A camera in the middle of the +z wall, looking across the room.
fn looking_in(size: Vec3) -> Camera {
    (
        Vec3::new(0.5 * size.x, 0.55 * size.y, size.z - 0.05),
        Quat::IDENTITY,
        1.2,
        1.3,
    )
}
