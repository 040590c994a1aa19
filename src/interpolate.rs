//! Vertex values for smooth shading: how per-element values (taken at the
//! element centres) become values at the mesh's vertices, which the camera
//! view interpolates across each element. Pure maths, no GPU.
//!
//! Two rules, each shown by the path-traced images (docs/accuracy.md):
//! - **Hidden elements do not vote.** An element that received no light at
//!   all (under a box, above a light panel hung under the ceiling) is not
//!   seen by the camera, and averaging its zero into its seen neighbours'
//!   vertices drew a dark halo around every such panel.
//! - **Edges are extrapolated, not averaged.** On a polygon's boundary a
//!   vertex is half an element away from the nearest element centres; the
//!   plain average gives it their value, so light that falls off towards a
//!   corner (the indirect light of a concave corner) showed as bright seams
//!   along every edge. On a quad's element lattice a boundary vertex is
//!   extrapolated linearly from the two nearest rows of centres (weights
//!   3/2 and -1/2; a linear function is then exact everywhere), clamped at 0.

use crate::mesh::Mesh;

/// Per mesh vertex, the value smooth shading shows there: `values` per
/// element, `hidden[j]` marking elements that no light reached (see the
/// module docs). Interior vertices average their elements; boundary vertices
/// of quad polygons are extrapolated; a vertex whose elements are all
/// hidden averages them all.
pub fn vertex_values(mesh: &Mesh, values: &[[f32; 3]], hidden: Option<&[bool]>) -> Vec<[f32; 3]> {
    let is_hidden = |j: usize| hidden.and_then(|h| h.get(j)).copied().unwrap_or(false);
    let n = mesh.vertices.len();
    // Seen elements' sums, then everything's, per vertex.
    let mut sums = [vec![[0.0f32; 3]; n], vec![[0.0f32; 3]; n]];
    let mut counts = [vec![0u32; n], vec![0u32; n]];
    for (j, (e, r)) in mesh.elements.iter().zip(values).enumerate() {
        let distinct = if e.vertices[3] == e.vertices[2] { 3 } else { 4 };
        for &v in &e.vertices[..distinct] {
            for (k, (sum, count)) in sums.iter_mut().zip(&mut counts).enumerate() {
                if k == 1 || !is_hidden(j) {
                    for c in 0..3 {
                        sum[v as usize][c] += r[c];
                    }
                    count[v as usize] += 1;
                }
            }
        }
    }
    let mut out: Vec<[f32; 3]> = (0..n)
        .map(|v| {
            let k = if counts[0][v] > 0 { 0 } else { 1 };
            sums[k][v].map(|x| x / counts[k][v].max(1) as f32)
        })
        .collect();
    for poly in &mesh.polygons {
        extrapolate_edges(mesh, poly, values, &is_hidden, &mut out);
    }
    out
}

/// The weights of the element centres (cell indices along one axis of `n`
/// cells) that give the value at lattice line `i` (0..=n): the two nearest
/// centres averaged inside, extrapolated at the ends.
fn weights(i: u32, n: u32) -> [(u32, f32); 2] {
    match (i, n) {
        (_, 1) => [(0, 1.0), (0, 0.0)],
        (0, _) => [(0, 1.5), (1, -0.5)],
        (i, n) if i == n => [(n - 1, 1.5), (n - 2, -0.5)],
        (i, _) => [(i - 1, 0.5), (i, 0.5)],
    }
}

/// Overwrites the boundary vertices of quad polygon `poly` with values
/// extrapolated over its element lattice, where none of the elements used is hidden.
fn extrapolate_edges(
    mesh: &Mesh,
    poly: &crate::mesh::MeshPolygon,
    values: &[[f32; 3]],
    is_hidden: &dyn Fn(usize) -> bool,
    out: &mut [[f32; 3]],
) {
    let first = poly.elements.start as usize;
    let Some(e0) = mesh.elements.get(first) else {
        return;
    };
    if e0.vertices[3] == e0.vertices[2] {
        return; // triangles: no lattice of rows and columns
    }
    let ([pu, pv], [eu, ev]) = (poly.patch_grid, poly.element_grid);
    let (nu, nv) = (pu * eu, pv * ev);
    if (nu * nv) as usize != poly.elements.len() {
        return;
    }
    // Element at lattice cell (i, j): patches row by row, their elements row by row.
    let cell = |i: u32, j: u32| -> usize {
        let (pi, pj, ei, ej) = (i / eu, j / ev, i % eu, j % ev);
        first + ((pj * pu + pi) * eu * ev + ej * eu + ei) as usize
    };
    let base = e0.vertices[0];
    for j in 0..=nv {
        for i in 0..=nu {
            if i != 0 && i != nu && j != 0 && j != nv {
                continue;
            }
            let mut value = [0.0f32; 3];
            let mut usable = true;
            for (ci, wi) in weights(i, nu) {
                for (cj, wj) in weights(j, nv) {
                    let w = wi * wj;
                    if w == 0.0 {
                        continue;
                    }
                    let k = cell(ci, cj);
                    usable &= !is_hidden(k);
                    for c in 0..3 {
                        value[c] += w * values[k][c];
                    }
                }
            }
            let v = (base + j * (nu + 1) + i) as usize;
            if usable && v < out.len() {
                out[v] = value.map(|x| x.max(0.0));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::unit_square as square;
    use glam::Vec3;

    #[test]
    fn a_linear_function_is_reproduced_at_every_vertex() {
        let mesh = square(3, 2);
        let f = |p: Vec3| 1.0 + 2.0 * p.x + 0.5 * p.y;
        let values: Vec<[f32; 3]> = mesh.elements.iter().map(|e| [f(e.centre); 3]).collect();
        let at = vertex_values(&mesh, &values, None);
        for (v, p) in mesh.vertices.iter().zip(&at) {
            assert!((p[0] - f(*v)).abs() < 1e-5, "{v}: {} vs {}", p[0], f(*v));
        }
    }

    #[test]
    fn hidden_elements_do_not_darken_their_seen_neighbours() {
        let mesh = square(2, 2);
        let hidden: Vec<bool> = mesh.elements.iter().map(|e| e.centre.x < 0.25).collect();
        let values: Vec<[f32; 3]> = hidden
            .iter()
            .map(|&h| if h { [0.0; 3] } else { [1.0; 3] })
            .collect();
        let at = vertex_values(&mesh, &values, Some(&hidden));
        for (v, p) in mesh.vertices.iter().zip(&at) {
            if v.x > 0.2 {
                assert_eq!(p[0], 1.0, "{v}");
            }
        }
        // Without the mask the seam between them is dimmed.
        let plain = vertex_values(&mesh, &values, None);
        let seam = mesh
            .vertices
            .iter()
            .position(|v| (v.x - 0.25).abs() < 1e-6 && (v.y - 0.5).abs() < 1e-6)
            .expect("a vertex on the seam");
        assert_eq!(plain[seam][0], 0.5);
    }
}
