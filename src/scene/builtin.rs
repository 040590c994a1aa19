//! Built-in scenes, generated as glTF text so they go through the same loader
//! as files (and can be written out with `radiosity scene NAME --out FILE`).

use super::gltf_write::{box_faces, write_gltf, GltfSurface};
use super::Subdivision;
use glam::{Quat, Vec3};

/// Names accepted by [`builtin_gltf`] (`cubes-N` takes any N from 1 to 40).
pub fn builtin_names() -> Vec<&'static str> {
    vec![
        "cornell",
        "cubes-N",
        "cubes-b1",
        "cubes-b2",
        "cubes-b3",
        "classroom-c1",
        "classroom-c2",
        "classroom-c3",
        "family-KIND-SEED",
    ]
}

/// The glTF text of a built-in scene, or `None` for an unknown name.
pub fn builtin_gltf(name: &str) -> Option<String> {
    match name {
        "cornell" => Some(cornell()),
        // The paper's benchmark scenes B1-B3 (DESIGN.md section 4).
        "cubes-b1" => Some(cubes(16)),
        "cubes-b2" => Some(cubes(20)),
        "cubes-b3" => Some(cubes(26)),
        // The paper's classroom scenes C1-C3: 36, 54 and 90 seats.
        "classroom-c1" => Some(classroom(6, 6)),
        "classroom-c2" => Some(classroom(6, 9)),
        "classroom-c3" => Some(classroom(9, 10)),
        _ if name.starts_with("family-") => super::family::family_gltf(name),
        _ => {
            let n: u32 = name.strip_prefix("cubes-")?.parse().ok()?;
            (1..=40).contains(&n).then(|| cubes(n))
        }
    }
}

/// The paper's benchmark: a 10 m room (10 x 10 patches of 2 x 2 elements per
/// face) lit by a box light under the ceiling (2 x 2 patches of one element per
/// face), holding an n x n x n grid of cubes (2 patches of 2 x 2 elements per face).
fn cubes(n: u32) -> String {
    let room = GltfSurface {
        name: "room".into(),
        polygons: box_faces(Vec3::ZERO, Vec3::splat(10.0), false),
        reflectance: [0.6; 3],
        emission: [0.0; 3],
        double_sided: false,
        subdivision: Some(Subdivision {
            patches: [10, 10],
            elements: [2, 2],
        }),
    };
    let light = GltfSurface {
        name: "light".into(),
        polygons: box_faces(Vec3::new(4.0, 9.2, 4.0), Vec3::new(6.0, 9.6, 6.0), true),
        reflectance: [0.0; 3],
        emission: [20.0; 3],
        double_sided: false,
        subdivision: Some(Subdivision {
            patches: [2, 2],
            elements: [1, 1],
        }),
    };
    let spacing = 7.0 / n as f32;
    let edge = 0.5 * spacing;
    let mut cubes = Vec::with_capacity((n * n * n * 6) as usize);
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                let lo = Vec3::new(1.5, 1.0, 1.5)
                    + Vec3::new(i as f32, j as f32, k as f32) * spacing
                    + Vec3::splat(0.25 * spacing);
                cubes.extend(box_faces(lo, lo + Vec3::splat(edge), true));
            }
        }
    }
    let cubes = GltfSurface {
        name: "cubes".into(),
        polygons: cubes,
        reflectance: [0.7, 0.6, 0.5],
        emission: [0.0; 3],
        double_sided: false,
        subdivision: Some(Subdivision {
            patches: [2, 1],
            elements: [2, 2],
        }),
    };
    // Inside the room by the +z wall, looking down -z at the grid.
    let camera = (
        Vec3::new(5.0, 4.5, 9.9),
        glam::Quat::IDENTITY,
        1.3f32,
        1.0f32,
    );
    write_gltf(&[room, light, cubes], Some(camera))
}

const WHITE: [f32; 3] = [0.73, 0.73, 0.73];
const RED: [f32; 3] = [0.63, 0.065, 0.05];
const GREEN: [f32; 3] = [0.14, 0.45, 0.091];

/// Turns millimetre corner lists into metres, each polygon oriented so its
/// front faces `towards` (inward) or away from it (outward).
fn oriented(quads: &[[[f32; 3]; 4]], reference: Vec3, facing_reference: bool) -> Vec<Vec<Vec3>> {
    quads
        .iter()
        .map(|q| {
            let mut v: Vec<Vec3> = q.iter().map(|p| Vec3::from(*p) * 1e-3).collect();
            let n = (v[2] - v[0]).cross(v[3] - v[1]);
            let centre = v.iter().copied().sum::<Vec3>() / 4.0;
            let faces = n.dot(reference - centre) > 0.0;
            if faces != facing_reference {
                v.reverse();
            }
            v
        })
        .collect()
}

fn surface(
    name: &str,
    polygons: Vec<Vec<Vec3>>,
    reflectance: [f32; 3],
    emission: [f32; 3],
    grid: Grid,
) -> GltfSurface {
    let subdivision = Some(Subdivision {
        patches: grid.0,
        elements: grid.1,
    });
    GltfSurface {
        name: name.into(),
        polygons,
        reflectance,
        emission,
        double_sided: false,
        subdivision,
    }
}

/// Patches per polygon and elements per patch.
type Grid = ([u32; 2], [u32; 2]);

// Subdivisions of the Cornell box, fixed in the file as a modeller would, so
// the default render is quick: the automatic rule would give about 1000
// patches. Patches of about 5.5 cm everywhere (10 x 10 on the walls, the
// tall block's sides 6 high), 2 x 2 elements each: every surface within
// 0.5 % of a fine solution. (8 x 8 on the walls and 3 x 3 on both blocks
// left the blocks 0.8-1.05 % low; 6 x 6, 2 % low.)
const CORNELL_WALL: Grid = ([10, 10], [2, 2]);
const CORNELL_BLOCK: Grid = ([3, 3], [2, 2]);
const CORNELL_TALL_BLOCK: Grid = ([6, 3], [2, 2]);
const CORNELL_LIGHT: Grid = ([2, 2], [2, 2]);

/// A quad's corners.
type Quad = [[f32; 3]; 4];

// The Cornell box's measured geometry, millimetres.
const CORNELL_MM_FLOOR: [Quad; 1] = [[
    [552.8, 0.0, 0.0],
    [0.0, 0.0, 0.0],
    [0.0, 0.0, 559.2],
    [549.6, 0.0, 559.2],
]];
const CORNELL_MM_CEILING: [Quad; 1] = [[
    [556.0, 548.8, 0.0],
    [556.0, 548.8, 559.2],
    [0.0, 548.8, 559.2],
    [0.0, 548.8, 0.0],
]];
const CORNELL_MM_BACK: [Quad; 1] = [[
    [549.6, 0.0, 559.2],
    [0.0, 0.0, 559.2],
    [0.0, 548.8, 559.2],
    [556.0, 548.8, 559.2],
]];
const CORNELL_MM_RIGHT_GREEN: [Quad; 1] = [[
    [0.0, 0.0, 559.2],
    [0.0, 0.0, 0.0],
    [0.0, 548.8, 0.0],
    [0.0, 548.8, 559.2],
]];
const CORNELL_MM_LEFT_RED: [Quad; 1] = [[
    [552.8, 0.0, 0.0],
    [549.6, 0.0, 559.2],
    [556.0, 548.8, 559.2],
    [556.0, 548.8, 0.0],
]];
const CORNELL_MM_LIGHT: [Quad; 1] = [[
    [343.0, 547.8, 227.0],
    [343.0, 547.8, 332.0],
    [213.0, 547.8, 332.0],
    [213.0, 547.8, 227.0],
]];
const CORNELL_MM_SHORT_BLOCK: [Quad; 5] = [
    [
        [130.0, 165.0, 65.0],
        [82.0, 165.0, 225.0],
        [240.0, 165.0, 272.0],
        [290.0, 165.0, 114.0],
    ],
    [
        [290.0, 0.0, 114.0],
        [290.0, 165.0, 114.0],
        [240.0, 165.0, 272.0],
        [240.0, 0.0, 272.0],
    ],
    [
        [130.0, 0.0, 65.0],
        [130.0, 165.0, 65.0],
        [290.0, 165.0, 114.0],
        [290.0, 0.0, 114.0],
    ],
    [
        [82.0, 0.0, 225.0],
        [82.0, 165.0, 225.0],
        [130.0, 165.0, 65.0],
        [130.0, 0.0, 65.0],
    ],
    [
        [240.0, 0.0, 272.0],
        [240.0, 165.0, 272.0],
        [82.0, 165.0, 225.0],
        [82.0, 0.0, 225.0],
    ],
];
const CORNELL_MM_TALL_BLOCK: [Quad; 5] = [
    [
        [423.0, 330.0, 247.0],
        [265.0, 330.0, 296.0],
        [314.0, 330.0, 456.0],
        [472.0, 330.0, 406.0],
    ],
    [
        [423.0, 0.0, 247.0],
        [423.0, 330.0, 247.0],
        [472.0, 330.0, 406.0],
        [472.0, 0.0, 406.0],
    ],
    [
        [472.0, 0.0, 406.0],
        [472.0, 330.0, 406.0],
        [314.0, 330.0, 456.0],
        [314.0, 0.0, 456.0],
    ],
    [
        [314.0, 0.0, 456.0],
        [314.0, 330.0, 456.0],
        [265.0, 330.0, 296.0],
        [265.0, 0.0, 296.0],
    ],
    [
        [265.0, 0.0, 296.0],
        [265.0, 330.0, 296.0],
        [423.0, 330.0, 247.0],
        [423.0, 0.0, 247.0],
    ],
];

/// The Cornell box from the Cornell Program of Computer Graphics' measured
/// data (millimetres, converted to metres), open at the front, with the light
/// quad 1 mm below the ceiling facing down.
fn cornell() -> String {
    let room_centre = Vec3::new(0.278, 0.274, 0.280);
    let short_centre = Vec3::new(0.186, 0.0825, 0.1685);
    let tall_centre = Vec3::new(0.3685, 0.165, 0.3515);
    let surfaces = vec![
        surface(
            "floor",
            oriented(&CORNELL_MM_FLOOR, room_centre, true),
            WHITE,
            [0.0; 3],
            CORNELL_WALL,
        ),
        surface(
            "ceiling",
            oriented(&CORNELL_MM_CEILING, room_centre, true),
            WHITE,
            [0.0; 3],
            CORNELL_WALL,
        ),
        surface(
            "back_wall",
            oriented(&CORNELL_MM_BACK, room_centre, true),
            WHITE,
            [0.0; 3],
            CORNELL_WALL,
        ),
        surface(
            "right_wall_green",
            oriented(&CORNELL_MM_RIGHT_GREEN, room_centre, true),
            GREEN,
            [0.0; 3],
            CORNELL_WALL,
        ),
        surface(
            "left_wall_red",
            oriented(&CORNELL_MM_LEFT_RED, room_centre, true),
            RED,
            [0.0; 3],
            CORNELL_WALL,
        ),
        surface(
            "light",
            oriented(&CORNELL_MM_LIGHT, Vec3::new(0.278, 0.0, 0.2795), true),
            [0.78; 3],
            [17.0, 12.0, 4.0],
            CORNELL_LIGHT,
        ),
        surface(
            "short_block",
            oriented(&CORNELL_MM_SHORT_BLOCK, short_centre, false),
            WHITE,
            [0.0; 3],
            CORNELL_BLOCK,
        ),
        surface(
            "tall_block",
            oriented(&CORNELL_MM_TALL_BLOCK, tall_centre, false),
            WHITE,
            [0.0; 3],
            CORNELL_TALL_BLOCK,
        ),
    ];
    // The camera at (278, 273, -800) mm looks down +Z: glTF cameras look down
    // their local -Z, so turn half a turn about Y. 35 mm lens, 25 mm film.
    let yfov = 2.0 * (12.5f32 / 35.0).atan();
    let camera = (
        Vec3::new(0.278, 0.273, -0.8),
        Quat::from_rotation_y(std::f32::consts::PI),
        yfov,
        1.0,
    );
    write_gltf(&surfaces, Some(camera))
}

/// The parts of a classroom, each a glTF node holding that part of every
/// desk, chair or fitting, with one subdivision.
struct Parts {
    surfaces: Vec<GltfSurface>,
}

impl Parts {
    fn part(&mut self, name: &str, reflectance: [f32; 3], emission: [f32; 3], grid: Grid) -> usize {
        let subdivision = Some(Subdivision {
            patches: grid.0,
            elements: grid.1,
        });
        self.surfaces.push(GltfSurface {
            name: name.into(),
            polygons: Vec::new(),
            reflectance,
            emission,
            double_sided: false,
            subdivision,
        });
        self.surfaces.len() - 1
    }

    /// A box with all six faces.
    fn solid(&mut self, part: usize, lo: Vec3, hi: Vec3) {
        self.surfaces[part].polygons.extend(box_faces(lo, hi, true));
    }

    /// A leg or post: the four sides only (its ends touch other surfaces).
    fn post(&mut self, part: usize, lo: Vec3, hi: Vec3) {
        let faces = box_faces(lo, hi, true);
        self.surfaces[part].polygons.extend(
            faces
                .into_iter()
                .enumerate()
                .filter(|(k, _)| *k != 2 && *k != 3)
                .map(|(_, f)| f),
        );
    }
}

/// A desk at `o` (its back-left-bottom corner), facing -z.
fn desk(p: &mut Parts, ids: &[usize; 5], o: Vec3) {
    let v = |x: f32, y: f32, z: f32| o + Vec3::new(x, y, z);
    p.solid(ids[0], v(0.0, 0.70, 0.0), v(1.0, 0.74, 0.5));
    for (x, z) in [(0.02, 0.02), (0.94, 0.02), (0.02, 0.44), (0.94, 0.44)] {
        p.post(ids[1], v(x, 0.0, z), v(x + 0.04, 0.70, z + 0.04));
    }
    p.solid(ids[2], v(0.06, 0.35, 0.0), v(0.94, 0.68, 0.02));
    p.solid(ids[3], v(0.06, 0.55, 0.05), v(0.94, 0.57, 0.45));
    p.solid(ids[4], v(0.06, 0.10, 0.03), v(0.94, 0.13, 0.06));
    p.solid(ids[4], v(0.06, 0.10, 0.44), v(0.94, 0.13, 0.47));
}

/// A chair at `o` (its front-left-bottom corner), backrest towards +z.
fn chair(p: &mut Parts, ids: &[usize; 4], o: Vec3) {
    let v = |x: f32, y: f32, z: f32| o + Vec3::new(x, y, z);
    p.solid(ids[0], v(0.0, 0.42, 0.0), v(0.42, 0.45, 0.42));
    p.solid(ids[1], v(0.0, 0.62, 0.39), v(0.42, 0.85, 0.42));
    for (x, z) in [(0.01, 0.01), (0.38, 0.01), (0.01, 0.38), (0.38, 0.38)] {
        p.post(ids[2], v(x, 0.0, z), v(x + 0.03, 0.42, z + 0.03));
    }
    for x in [0.03, 0.36] {
        p.post(ids[3], v(x, 0.45, 0.395), v(x + 0.03, 0.62, 0.415));
    }
}

/// A classroom's light sources in a room `w` x `h` x `d`: fluorescent
/// fittings under the ceiling and daylight windows along the +x wall.
fn fittings(p: &mut Parts, w: f32, d: f32, h: f32) {
    // Fluorescent fittings under the ceiling: a grid of 4 x 3 boxes.
    let lights = p.part(
        "ceiling_lights",
        [0.8; 3],
        [25.0, 24.0, 22.0],
        ([2, 1], [1, 2]),
    );
    for i in 0..4 {
        for j in 0..3 {
            let (x, z) = ((i as f32 + 0.5) * w / 4.0, (j as f32 + 0.5) * d / 3.0);
            p.solid(
                lights,
                Vec3::new(x - 0.6, h - 0.12, z - 0.15),
                Vec3::new(x + 0.6, h - 0.02, z + 0.15),
            );
        }
    }
    // Windows along the +x wall: daylight panes 1 cm in front of the wall.
    let windows = p.part("windows", [0.1; 3], [6.0, 7.0, 9.0], ([2, 2], [2, 2]));
    for k in 0..6 {
        let z = 1.0 + k as f32 * (d - 2.0) / 6.0;
        let (z0, z1, y0, y1) = (z + 0.1, z + (d - 2.0) / 6.0 - 0.1, 0.9, 2.6);
        let x = w - 0.01;
        p.surfaces[windows].polygons.push(vec![
            Vec3::new(x, y0, z0),
            Vec3::new(x, y0, z1),
            Vec3::new(x, y1, z1),
            Vec3::new(x, y1, z0),
        ]);
    }
}

/// A classroom (DESIGN.md section 4, C1-C3): `rows` x `cols` seats (desk and
/// chair), a teacher's desk and chair, a blackboard, cabinets, ceiling lights
/// and windows. The counts per part are chosen so the scene's polygons,
/// patches and elements land near the paper's Table 2.
fn classroom(rows: u32, cols: u32) -> String {
    let (pitch_x, pitch_z) = (1.3f32, 1.2f32);
    let (w, d, h) = (
        cols as f32 * pitch_x + 2.0,
        rows as f32 * pitch_z + 4.0,
        3.0f32,
    );
    let mut p = Parts {
        surfaces: Vec::new(),
    };
    let wood = [0.55, 0.4, 0.25];
    let metal = [0.35, 0.35, 0.38];
    let desk_ids = [
        p.part("desk_tops", wood, [0.0; 3], ([2, 2], [2, 1])),
        p.part("desk_legs", metal, [0.0; 3], ([1, 1], [1, 3])),
        p.part("desk_panels", wood, [0.0; 3], ([3, 1], [2, 2])),
        p.part("desk_shelves", wood, [0.0; 3], ([1, 1], [2, 2])),
        p.part("desk_bars", metal, [0.0; 3], ([1, 1], [1, 1])),
    ];
    let chair_ids = [
        p.part("chair_seats", [0.3, 0.35, 0.5], [0.0; 3], ([2, 2], [1, 2])),
        p.part("chair_backs", [0.3, 0.35, 0.5], [0.0; 3], ([2, 2], [1, 2])),
        p.part("chair_legs", metal, [0.0; 3], ([1, 1], [1, 3])),
        p.part("chair_posts", metal, [0.0; 3], ([1, 1], [1, 2])),
    ];
    for r in 0..rows {
        for c in 0..cols {
            let o = Vec3::new(1.0 + c as f32 * pitch_x, 0.0, 3.0 + r as f32 * pitch_z);
            desk(&mut p, &desk_ids, o);
            chair(&mut p, &chair_ids, o + Vec3::new(0.29, 0.0, 0.55));
        }
    }
    // The teacher's desk and chair at the front, facing the class.
    desk(&mut p, &desk_ids, Vec3::new(w / 2.0 - 0.5, 0.0, 1.2));
    chair(&mut p, &chair_ids, Vec3::new(w / 2.0 - 0.21, 0.0, 0.6));
    let room = p.part("room", [0.7, 0.7, 0.65], [0.0; 3], ([8, 8], [3, 3]));
    p.surfaces[room].polygons = box_faces(Vec3::ZERO, Vec3::new(w, h, d), false);
    let board = p.part("blackboard", [0.08, 0.15, 0.1], [0.0; 3], ([4, 2], [2, 2]));
    p.solid(
        board,
        Vec3::new(w / 2.0 - 2.0, 0.9, 0.0),
        Vec3::new(w / 2.0 + 2.0, 2.1, 0.04),
    );
    let cabinets = p.part("cabinets", wood, [0.0; 3], ([2, 2], [2, 2]));
    let count = 8;
    for k in 0..count {
        let x = 0.5 + k as f32 * (w - 1.0) / count as f32;
        p.solid(
            cabinets,
            Vec3::new(x, 0.0, d - 0.5),
            Vec3::new(x + 0.8 * (w - 1.0) / count as f32, 1.2, d - 0.02),
        );
    }
    fittings(&mut p, w, d, h);
    // From the back corner, looking at the blackboard.
    let camera = (
        Vec3::new(w * 0.5, 2.2, d - 0.6),
        glam::Quat::from_rotation_x(-0.25),
        1.1f32,
        1.5f32,
    );
    write_gltf(&p.surfaces, Some(camera))
}
