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
//! A third criterion asks what the camera image will make of the light
//! ([`shading_error`], `--refine-shading`): the image traces the direct
//! light per pixel and shades only the solution's indirect part smoothly
//! between element centres, which is exact for a linear field; where a
//! patch's elements stray from the mean of their shaded corners by more
//! than [`crate::mesh::MeshSettings::shading_tol`] of the light the patch
//! holds (relative, as the eye and the image's SMAPE judge a dim room like
//! a bright one), its polygon's patch grid is doubled. Finer elements alone
//! (the patches kept) were tried first and did nothing for the room lit
//! through an opening: what its image needs is smaller shooters near the
//! corners where its light pool meets the walls. Rank 0 judges the whole
//! gathered solution and the verdicts are summed over ranks, so the mesh
//! is the same on any rank count.
//!
//! The criteria read only quantities that every rank count computes
//! identically (the shooters' powers and fixed-point shares summed over
//! ranks), so the refined mesh does not depend on the rank count.

use crate::mesh::Mesh;

/// A polygon's shooters are halved when one of them put more than this
/// fraction of the emitted power onto partly visible receivers; a pass ends
/// when no shooter left has this much power.
pub const SHOOTER_TOL: f64 = 0.002;

/// Patches whose mean radiosity is below this fraction of the scene's
/// (emitted power over total area) are left to the other criteria: their
/// shading error is a fraction of almost nothing.
pub const SHADING_FLOOR: f64 = 1e-3;

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
    /// How far smooth shading of its indirect light strays from its
    /// elements' values, relative to the light it holds ([`shading_error`]).
    pub shading: f64,
}

/// What a pass decides for one polygon.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Decision {
    /// Its shooters cast penumbrae (see [`SHOOTER_TOL`]).
    pub shooter: bool,
    /// Its receivers hold their light unevenly (see the module docs).
    pub receiver: bool,
    /// The camera image would shade its indirect light badly (see
    /// [`shading_error`]).
    pub shading: bool,
}

impl Decision {
    /// Whether the polygon's patch grid is doubled.
    pub fn refine(&self) -> bool {
        self.shooter || self.receiver || self.shading
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

/// Per polygon: whether to double its patch grid, and why (`receiver_tol`
/// and `shading_tol`: see the module docs; 0 turns that criterion off).
pub fn decide(
    mesh: &Mesh,
    patches: &[PatchStats],
    emitted: f64,
    receiver_tol: f64,
    shading_tol: f64,
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
                shading: shading_tol > 0.0 && own.iter().any(|p| p.shading > shading_tol),
            }
        })
        .collect()
}

/// Per patch: how far the camera image's smooth shading of the solution's
/// indirect light (`radiosity` less `direct`, per element) strays from the
/// elements' own values, relative to the light the patch holds: the sum
/// over its elements of area x |indirect - the mean of its corners' shaded
/// values|, over the sum of area x radiosity (channels summed). The image
/// traces the direct light per pixel, so only the indirect part is ever
/// interpolated; a linear field is shaded exactly, so this measures its
/// curvature (and the steps of indirect shadows) over the element size.
/// `unlit` elements are left out, as the image leaves them out; patches
/// dimmer than [`SHADING_FLOOR`] of the scene's mean radiosity get 0.
pub fn shading_error(
    mesh: &Mesh,
    radiosity: &[[f64; 3]],
    direct: &[[f64; 3]],
    unlit: &[bool],
    emitted: f64,
) -> Vec<f64> {
    let indirect: Vec<[f32; 3]> = radiosity
        .iter()
        .zip(direct)
        .map(|(b, d)| [0, 1, 2].map(|c| (b[c] - d[c]) as f32))
        .collect();
    let shaded = crate::interpolate::vertex_values(mesh, &indirect, Some(unlit));
    let area: f64 = mesh.elements.iter().map(|e| e.area).sum();
    let floor = if area > 0.0 {
        SHADING_FLOOR * emitted / area
    } else {
        0.0
    };
    mesh.patches
        .iter()
        .map(|p| {
            let (mut err, mut light) = (0.0, 0.0);
            for j in p.elements.clone() {
                let j = j as usize;
                if unlit.get(j).copied().unwrap_or(false) {
                    continue;
                }
                let e = &mesh.elements[j];
                let distinct = if e.vertices[3] == e.vertices[2] { 3 } else { 4 };
                let corners = &e.vertices[..distinct];
                for c in 0..3 {
                    let shown = corners
                        .iter()
                        .map(|&v| f64::from(shaded[v as usize][c]))
                        .sum::<f64>()
                        / distinct as f64;
                    err += e.area * (f64::from(indirect[j][c]) - shown).abs();
                    light += e.area * radiosity[j][c];
                }
            }
            if light <= floor * p.area || light <= 0.0 {
                0.0
            } else {
                err / light
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
            shading: 0.0,
        };
        assert!(!decide(&mesh, &patches, 1.0, TOL, 0.0)[0].refine());
        // With a 10 % share: 0.01 of the emitted power, refined.
        patches[1].penumbra = [one / 10, one];
        let d = decide(&mesh, &patches, 1.0, TOL, 0.0)[0];
        assert!(d.shooter && !d.receiver, "{d:?}");
    }

    /// `f` at every element centre of `mesh`.
    fn field(mesh: &Mesh, f: impl Fn(f32, f32) -> f64) -> Vec<[f64; 3]> {
        mesh.elements
            .iter()
            .map(|e| [f(e.centre.x, e.centre.y); 3])
            .collect()
    }

    fn mean(v: &[f64]) -> f64 {
        v.iter().sum::<f64>() / v.len() as f64
    }

    #[test]
    fn shading_error_sees_curvature_of_the_indirect_light_only() {
        let mesh = crate::mesh::unit_square(4, 2);
        let n = mesh.elements.len();
        let (none, unlit) = (vec![[0.0; 3]; n], vec![false; n]);
        // Smooth shading reproduces a linear field exactly (interior
        // vertices average, edges extrapolate).
        let linear = field(&mesh, |x, y| 1.0 + f64::from(x) + 2.0 * f64::from(y));
        let e = shading_error(&mesh, &linear, &none, &unlit, 1.0);
        assert!(e.iter().all(|&x| x < 1e-6), "{e:?}");
        // A curved one is not, and halving the elements quarters the error.
        let bowl = |x: f32, _: f32| 1.0 + 4.0 * f64::from(x - 0.5).powi(2);
        let coarse = mean(&shading_error(
            &mesh,
            &field(&mesh, bowl),
            &none,
            &unlit,
            1.0,
        ));
        let fine_mesh = crate::mesh::unit_square(8, 2);
        let m = fine_mesh.elements.len();
        let fine = mean(&shading_error(
            &fine_mesh,
            &field(&fine_mesh, bowl),
            &vec![[0.0; 3]; m],
            &vec![false; m],
            1.0,
        ));
        assert!(coarse > 1e-3, "{coarse}");
        assert!((0.15..0.4).contains(&(fine / coarse)), "{fine} / {coarse}");
        // The direct part is traced per pixel, never shaded: a curved
        // direct part on a linear indirect one costs nothing.
        let bump = field(&mesh, |x, _| 4.0 * f64::from(x - 0.5).powi(2));
        let total: Vec<[f64; 3]> = linear
            .iter()
            .zip(&bump)
            .map(|(a, b)| [0, 1, 2].map(|c| a[c] + b[c]))
            .collect();
        let e = shading_error(&mesh, &total, &bump, &unlit, 1.0);
        assert!(e.iter().all(|&x| x < 1e-6), "{e:?}");
        // Patches far dimmer than the scene's mean are left alone.
        let e = shading_error(&mesh, &field(&mesh, bowl), &none, &unlit, 1e6);
        assert!(e.iter().all(|&x| x == 0.0), "{e:?}");
    }

    #[test]
    fn polygons_whose_shading_strays_are_refined() {
        let mesh = square();
        let mut patches = vec![PatchStats::default(); mesh.patches.len()];
        patches[3].shading = 0.5 * 0.08;
        assert!(!decide(&mesh, &patches, 1.0, TOL, 0.08)[0].refine());
        patches[3].shading = 2.0 * 0.08;
        let d = decide(&mesh, &patches, 1.0, TOL, 0.08)[0];
        assert!(d.shading && !d.receiver && !d.shooter, "{d:?}");
        assert!(!decide(&mesh, &patches, 1.0, TOL, 0.0)[0].refine());
    }

    #[test]
    fn receivers_refine_by_the_power_they_hold_unevenly() {
        let mesh = square();
        let mut patches = vec![PatchStats::default(); mesh.patches.len()];
        patches[2].uneven = 0.5 * TOL;
        assert!(!decide(&mesh, &patches, 1.0, TOL, 0.0)[0].refine());
        patches[2].uneven = 2.0 * TOL;
        let d = decide(&mesh, &patches, 1.0, TOL, 0.0)[0];
        assert!(d.receiver && !d.shooter, "{d:?}");
        // A tolerance of 0 turns the criterion off.
        assert!(!decide(&mesh, &patches, 1.0, 0.0, 0.0)[0].refine());
    }
}
