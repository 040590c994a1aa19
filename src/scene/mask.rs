//! Alpha cut-outs (`alphaMode: MASK`, issue 64 item 5): a masked triangle
//! is cut into the pieces where its base colour's alpha passes the cutoff,
//! and only those pieces are surfaces. Everything downstream (the
//! hemispheres, the rays, the transport, the picture) then sees the holes
//! as geometry, so light and picture agree by construction and no drawing
//! or tracing path needs a texture.
//!
//! The triangle is split into an n x n barycentric grid of small triangles
//! (n about one per texel along its longest edge in texture space, at most
//! [`MAX_CUTS`], fewer where a scene has many masked triangles:
//! [`cuts_for`]); each is kept where the alpha (bilinear, times the factor's
//! alpha) at its centroid is at least the cutoff, as a fragment would be.
//! Neighbouring kept triangles of a row are joined into parallelograms, so
//! a wholly opaque triangle stays one polygon and a mask of stripes costs a
//! few pieces a row. The cut is as fine as one texel or an n-th of the
//! triangle, whichever is coarser: a leaf texture on a large quad keeps its
//! leaves' coverage, not their outline.

use super::texture::TexMap;
use glam::Vec3;

/// Pieces along each edge of a masked triangle at most.
pub const MAX_CUTS: u32 = 8;

/// Small triangles the masked triangles of a scene may be cut into in all
/// (n^2 each): what bounds the polygons a mask adds. Sponza's 19 444 masked
/// triangles (its plants and chains) are cut 2 x 2: 8 x 8 made 1.12 million
/// polygons of its 288 718 and 4.6 GB; 2 x 2 makes 312 876 and 1.7 GB.
pub const CUT_BUDGET: usize = 1 << 17;

/// Pieces along each edge of a masked triangle at most, for a scene with
/// `masked` masked triangles: [`MAX_CUTS`] within [`CUT_BUDGET`], at least 1.
pub fn cuts_for(masked: usize) -> u32 {
    let n = (CUT_BUDGET as f64 / masked.max(1) as f64).sqrt().floor() as u32;
    n.clamp(1, MAX_CUTS)
}

/// A material's `alphaMode: MASK`: its `alphaCutoff` and its
/// baseColorFactor's alpha.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mask {
    /// Alpha below this is cut out (glTF's default 0.5).
    pub cutoff: f32,
    /// The factor's alpha, multiplying the texture's.
    pub factor: f32,
}

/// The pieces of triangle `t` (counter-clockwise) where `mask` passes,
/// each counter-clockwise as `t` is: `t` itself where all of it passes,
/// nothing where none does. `map` gives the alpha (without one the factor
/// alone decides, for the whole triangle).
pub fn cut(t: [Vec3; 3], map: Option<&TexMap>, mask: Mask, most: u32) -> Vec<Vec<Vec3>> {
    let Some(map) = map else {
        return match mask.factor >= mask.cutoff {
            true => vec![t.to_vec()],
            false => Vec::new(),
        };
    };
    let n = cuts(t, map).min(most).max(1);
    let texture = &map.texture.texture;
    let at = |i: u32, j: u32| {
        t[0] + (t[1] - t[0]) * (i as f32 / n as f32) + (t[2] - t[0]) * (j as f32 / n as f32)
    };
    let passes = |c: [Vec3; 3]| {
        let centre = (c[0] + c[1] + c[2]) / 3.0;
        texture.alpha(map.uv(centre)) * mask.factor >= mask.cutoff
    };
    // Per row j: up triangles i = 0..n-j, down triangles i = 0..n-j-1.
    let rows: Vec<(Vec<bool>, Vec<bool>)> = (0..n)
        .map(|j| {
            let up = (0..n - j)
                .map(|i| passes([at(i, j), at(i + 1, j), at(i, j + 1)]))
                .collect();
            let down = (0..n - j - 1)
                .map(|i| passes([at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]))
                .collect();
            (up, down)
        })
        .collect();
    if rows.iter().all(|(u, d)| u.iter().chain(d).all(|&k| k)) {
        return vec![t.to_vec()];
    }
    let mut pieces = Vec::new();
    for (j, (up, down)) in rows.iter().enumerate() {
        let j = j as u32;
        let mut i = 0u32;
        while (i as usize) < up.len() {
            let full = |k: u32| up[k as usize] && down.get(k as usize) == Some(&true);
            if full(i) {
                // A run of whole cells: one parallelogram.
                let start = i;
                while full(i) {
                    i += 1;
                }
                pieces.push(vec![at(start, j), at(i, j), at(i, j + 1), at(start, j + 1)]);
                continue;
            }
            if up[i as usize] {
                pieces.push(vec![at(i, j), at(i + 1, j), at(i, j + 1)]);
            }
            if down.get(i as usize) == Some(&true) {
                pieces.push(vec![at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
            i += 1;
        }
    }
    pieces
}

/// Pieces along each edge of `t`: about one a texel along its longest edge
/// in texture space, 1 to [`MAX_CUTS`].
fn cuts(t: [Vec3; 3], map: &TexMap) -> u32 {
    let size = map.texture.texture.size();
    let texels = |a: Vec3, b: Vec3| {
        let d = map.uv(b) - map.uv(a);
        (d.x * size[0] as f32)
            .abs()
            .max((d.y * size[1] as f32).abs())
    };
    let longest = texels(t[0], t[1])
        .max(texels(t[1], t[2]))
        .max(texels(t[2], t[0]));
    (longest.ceil() as u32).clamp(1, MAX_CUTS)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::texture::{Texture, TextureRef, Wrap};
    use glam::Vec2;
    use std::sync::Arc;

    /// A `k` x `k` checkerboard of opaque and clear texels over the unit
    /// square's triangle (0,0), (1,0), (0,1), mapped uv = (x, z).
    fn checker(k: usize) -> TexMap {
        let rgba: Vec<[u8; 4]> = (0..k * k)
            .map(|i| {
                [
                    200,
                    200,
                    200,
                    if (i % k + i / k) % 2 == 0 { 255 } else { 0 },
                ]
            })
            .collect();
        let texture = Arc::new(TextureRef {
            index: 0,
            texture: Texture::from_srgb8("checker", k, k, &rgba, [Wrap::Repeat; 2]),
            encoded: Default::default(),
        });
        let p = [Vec3::ZERO, Vec3::X, Vec3::Z];
        TexMap::of_triangle(p, [Vec2::ZERO, Vec2::X, Vec2::Y], texture, [1.0; 3]).expect("map")
    }

    fn area(pieces: &[Vec<Vec3>]) -> f32 {
        pieces
            .iter()
            .map(|v| match v.len() {
                3 => 0.5 * (v[1] - v[0]).cross(v[2] - v[0]).length(),
                _ => 0.5 * (v[2] - v[0]).cross(v[3] - v[1]).length(),
            })
            .sum()
    }

    #[test]
    fn a_checkerboard_keeps_half_of_a_triangle_and_an_opaque_map_keeps_it_whole() {
        let t = [Vec3::ZERO, Vec3::X, Vec3::Z];
        let mask = Mask {
            cutoff: 0.5,
            factor: 1.0,
        };
        let pieces = cut(t, Some(&checker(8)), mask, MAX_CUTS);
        // 8 x 8 texels over the square, the triangle its lower half: the
        // diagonal's cells are halved, 28 whole cells and 8 halves, of
        // which the even ones pass.
        let kept = area(&pieces);
        assert!((kept - 0.25).abs() < 0.02, "kept {kept} of 0.5");
        // Every piece faces as the triangle does.
        for p in &pieces {
            let n = (p[1] - p[0]).cross(p[2] - p[0]);
            assert!(n.y < 0.0, "{p:?}");
        }
        // The factor's alpha under the cutoff cuts everything.
        let clear = Mask {
            cutoff: 0.5,
            factor: 0.4,
        };
        assert!(cut(t, Some(&checker(8)), clear, MAX_CUTS).is_empty());
        // A cutoff of 0 keeps the triangle as it was.
        let all = Mask {
            cutoff: 0.0,
            factor: 1.0,
        };
        assert_eq!(cut(t, Some(&checker(8)), all, MAX_CUTS), vec![t.to_vec()]);
        assert_eq!(cut(t, None, mask, MAX_CUTS), vec![t.to_vec()]);
    }
}
