//! Where on a mesh a point or a ray lands: the patch or element of a
//! polygon that holds a point, and the nearest other polygon along a ray
//! (the ambient transport's landings and the camera image's final gather).
//!
//! Pure geometry over [`Mesh`]: no GPU, no ranks.

use crate::mesh::Mesh;
use glam::Vec3;

/// The patch of polygon `polygon` that holds its point `x`: on a quad, the
/// cell of its patch grid at `x`'s bilinear coordinates; on a triangle, the
/// patch whose centre is nearest.
pub fn patch_at(mesh: &Mesh, polygon: u32, x: Vec3) -> u32 {
    let poly = &mesh.polygons[polygon as usize];
    let patches = poly.patches.clone();
    if patches.len() == 1 {
        return patches.start;
    }
    let [pu, pv] = poly.patch_grid;
    let first = &mesh.patches[patches.start as usize];
    if first.corners[3] != first.corners[2] && (pu * pv) as usize == patches.len() {
        let at = |i: u32, j: u32| &mesh.patches[(patches.start + j * pu + i) as usize];
        let quad = [
            at(0, 0).corners[0],
            at(pu - 1, 0).corners[1],
            at(pu - 1, pv - 1).corners[2],
            at(0, pv - 1).corners[3],
        ];
        let (u, v) = inverse_bilinear(&quad, x);
        let i = ((u * pu as f32) as u32).min(pu - 1);
        let j = ((v * pv as f32) as u32).min(pv - 1);
        return patches.start + j * pu + i;
    }
    patches
        .min_by(|&a, &b| {
            let da = mesh.patches[a as usize].centre.distance_squared(x);
            let db = mesh.patches[b as usize].centre.distance_squared(x);
            da.total_cmp(&db)
        })
        .unwrap_or(0)
}

/// The bilinear coordinates (u, v), clamped to the unit square, of the
/// point `x` of the planar quad `c` ([`crate::mesh::bilinear`]'s corners),
/// by Newton's method on the least-squares residual.
pub fn inverse_bilinear(c: &[Vec3; 4], x: Vec3) -> (f32, f32) {
    let (mut u, mut v) = (0.5f32, 0.5f32);
    for _ in 0..6 {
        let r = x - crate::mesh::bilinear(c, u, v);
        let du = (c[1] - c[0]) * (1.0 - v) + (c[2] - c[3]) * v;
        let dv = (c[3] - c[0]) * (1.0 - u) + (c[2] - c[1]) * u;
        let (a, b, d) = (du.dot(du), du.dot(dv), dv.dot(dv));
        let det = a * d - b * b;
        if det.abs() <= f32::EPSILON * a * d {
            break;
        }
        let (ru, rv) = (du.dot(r), dv.dot(r));
        let (su, sv) = ((d * ru - b * rv) / det, (a * rv - b * ru) / det);
        u = (u + su).clamp(0.0, 1.0);
        v = (v + sv).clamp(0.0, 1.0);
        // Converged (a parallelogram, bilinear only in name, takes one
        // step): the remaining steps would move it by rounding alone.
        if su.abs().max(sv.abs()) < 1e-6 {
            break;
        }
    }
    (u, v)
}

/// The nearest hit along the ray, skipping polygon `own` (a quad that is
/// not quite planar, as the measured Cornell box's left wall, meets a ray
/// leaving one of its triangles in its other one, a hair away).
pub fn nearest_other(
    mesh: &Mesh,
    origin: Vec3,
    dir: Vec3,
    own: u32,
) -> Option<crate::raytrace::Hit> {
    let mut t_min = 0.0;
    for _ in 0..4 {
        let hit = mesh
            .occluders
            .nearest_facing(origin, dir, t_min, f32::INFINITY, 1e-5)?;
        if hit.polygon != own {
            return Some(hit);
        }
        t_min = hit.t * (1.0 + 1e-5) + mesh.ray_offset;
    }
    None
}

/// The element of polygon `polygon` that holds its point `x`: on a quad,
/// the cell of its element grid at `x`'s bilinear coordinates; on a
/// triangle, the patch of its lattice at `x`'s barycentric coordinates and
/// in it the element whose centre is nearest.
pub fn element_at(mesh: &Mesh, polygon: u32, x: Vec3) -> u32 {
    let poly = &mesh.polygons[polygon as usize];
    let start = poly.elements.start;
    let first = &mesh.elements[start as usize];
    let ([pu, pv], [eu, ev]) = (poly.patch_grid, poly.element_grid);
    if first.corners[3] != first.corners[2] {
        let (nu, nv) = (pu * eu, pv * ev);
        // The quad's elements, patch by patch, each patch's row by row
        // (`Mesh::quad`).
        let at =
            |i: u32, j: u32| start + ((j / ev) * pu + i / eu) * (eu * ev) + (j % ev) * eu + i % eu;
        let corner = |i: u32, j: u32, k: usize| mesh.elements[at(i, j) as usize].corners[k];
        let quad = [
            corner(0, 0, 0),
            corner(nu - 1, 0, 1),
            corner(nu - 1, nv - 1, 2),
            corner(0, nv - 1, 3),
        ];
        let (u, v) = inverse_bilinear(&quad, x);
        let i = ((u * nu as f32) as u32).min(nu - 1);
        let j = ((v * nv as f32) as u32).min(nv - 1);
        return at(i, j);
    }
    let patch = triangle_patch(mesh, polygon, x);
    let p = &mesh.patches[patch as usize];
    p.elements
        .clone()
        .min_by(|&a, &b| {
            let da = mesh.elements[a as usize].centre.distance_squared(x);
            let db = mesh.elements[b as usize].centre.distance_squared(x);
            da.total_cmp(&db)
        })
        .unwrap_or(start)
}

/// The patch of triangle `polygon`'s lattice (`Mesh::triangle`: row by
/// row, each cell's up triangle then its down one) holding its point `x`.
fn triangle_patch(mesh: &Mesh, polygon: u32, x: Vec3) -> u32 {
    let poly = &mesh.polygons[polygon as usize];
    let n = poly.patch_grid[0];
    let first = poly.patches.start;
    // The cells before row j: 2 (n - r) - 1 in each row r < j.
    let index = |i: u32, j: u32, down: bool| first + j * (2 * n - j) + 2 * i + down as u32;
    let corner = |p: u32, k: usize| mesh.patches[p as usize].corners[k];
    let v0 = corner(index(0, 0, false), 0);
    let e1 = corner(index(n - 1, 0, false), 1) - v0;
    let e2 = corner(index(0, n - 1, false), 2) - v0;
    let d = x - v0;
    let (a11, a12, a22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let det = a11 * a22 - a12 * a12;
    if det.abs() <= f32::EPSILON * a11 * a22 {
        return first;
    }
    let (r1, r2) = (e1.dot(d), e2.dot(d));
    let a = ((a22 * r1 - a12 * r2) / det * n as f32).max(0.0);
    let b = ((a11 * r2 - a12 * r1) / det * n as f32).max(0.0);
    let j = (b as u32).min(n - 1);
    let i = (a as u32).min(n - 1 - j);
    let down = i + j + 1 < n && a.fract() + b.fract() > 1.0;
    index(i, j, down)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::MeshSettings;
    use crate::scene::{Polygon, Scene, Subdivision};

    #[test]
    fn a_point_of_a_quad_finds_its_patch() {
        // A skewed planar quad of 3 x 2 patches.
        let mut poly = Polygon::square(Vec3::ZERO, 1.0, Vec3::X, Vec3::Y, [0.5; 3], [0.0; 3]);
        poly.vertices[2] += Vec3::new(0.6, 0.3, 0.0);
        poly.subdivision = Some(Subdivision {
            patches: [3, 2],
            elements: [2, 2],
        });
        let scene = Scene {
            nodes: vec!["q".into()],
            polygons: vec![poly],
            ..Default::default()
        };
        let mesh = Mesh::build(&scene, &MeshSettings::default());
        assert_eq!(mesh.patches.len(), 6);
        for (k, p) in mesh.patches.iter().enumerate() {
            assert_eq!(patch_at(&mesh, 0, p.centre), k as u32);
            for e in &mesh.elements[p.elements.start as usize..p.elements.end as usize] {
                assert_eq!(patch_at(&mesh, 0, e.centre), k as u32);
            }
        }
        let c = [
            scene.polygons[0].vertices[0],
            scene.polygons[0].vertices[1],
            scene.polygons[0].vertices[2],
            scene.polygons[0].vertices[3],
        ];
        for (u, v) in [(0.1, 0.9), (0.5, 0.5), (0.93, 0.07), (0.3, 0.6)] {
            let (a, b) = inverse_bilinear(&c, crate::mesh::bilinear(&c, u, v));
            assert!(
                (a - u).abs() < 1e-5 && (b - v).abs() < 1e-5,
                "({u}, {v}) -> ({a}, {b})"
            );
        }
    }

    #[test]
    fn a_point_of_an_element_finds_it_on_quads_and_triangles() {
        let mut quad = Polygon::square(Vec3::ZERO, 1.0, Vec3::X, Vec3::Y, [0.5; 3], [0.0; 3]);
        quad.vertices[2] += Vec3::new(0.6, 0.3, 0.0);
        quad.subdivision = Some(Subdivision {
            patches: [3, 2],
            elements: [2, 3],
        });
        let mut tri = Polygon::square(Vec3::ZERO, 1.0, Vec3::X, Vec3::Y, [0.5; 3], [0.0; 3]);
        tri.vertices = vec![
            Vec3::new(0.0, 0.0, 1.0),
            Vec3::new(2.0, 0.3, 1.0),
            Vec3::new(0.4, 1.7, 1.0),
        ];
        tri.subdivision = Some(Subdivision {
            patches: [4, 4],
            elements: [3, 3],
        });
        let scene = Scene {
            nodes: vec!["q".into()],
            polygons: vec![quad, tri],
            ..Default::default()
        };
        let mesh = Mesh::build(&scene, &MeshSettings::default());
        for (k, e) in mesh.elements.iter().enumerate() {
            assert_eq!(element_at(&mesh, e.polygon, e.centre), k as u32, "{e:?}");
        }
    }
}
