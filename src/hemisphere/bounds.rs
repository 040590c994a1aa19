//! Conservative cell rectangles: the cells a piece (four directions from
//! the hemisphere's centre) may cover, found in f64 and widened by a margin
//! far above the f32 rounding of the per-cell test, with an AVX2 twin of
//! the corners and edges that gives the scalar rectangle bit for bit.

use super::*;

/// A conservative rectangle of cells holding a planar piece's projection:
/// columns `x0..x1` and rows `y0..y1` in cell units (cell (p, t) spans
/// `t..t+1` by `p..p+1`). `x1` may exceed R_theta: the rectangle then wraps
/// past the theta = 0 seam.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellRect {
    /// First column (fractional).
    pub x0: f32,
    /// Last column (fractional, may exceed R_theta).
    pub x1: f32,
    /// First row.
    pub y0: f32,
    /// Last row.
    pub y1: f32,
}

/// The smallest arc of azimuth holding the unit directions `u`: its start,
/// its span, and whether every column is taken (a pole is inside, or a
/// corner lies on the axis).
fn azimuth_range(u: &[Vec3; 4]) -> (f32, f32, bool) {
    use std::f32::consts::{PI as PI32, TAU};
    // Angles and their differences lie within (-2 pi, 2 pi): one add wraps
    // them (floorf is a call on the baseline x86-64 target, 20 a piece).
    let wrap = |a: f32| if a < 0.0 { a + TAU } else { a };
    let mut full = false;
    let mut a = [0.0f32; 4];
    for k in 0..4 {
        if u[k].x * u[k].x + u[k].y * u[k].y < 1e-12 {
            full = true;
        }
        a[k] = wrap(crate::numeric::atan2_f32(u[k].y, u[k].x));
    }
    let (mut t0, mut span) = (0.0f32, TAU);
    for k in 0..4 {
        let s = (0..4).map(|j| wrap(a[j] - a[k])).fold(0.0f32, f32::max);
        if s < span {
            span = s;
            t0 = a[k];
        }
    }
    if span >= 0.999 * PI32 {
        full = true;
    }
    (t0, span, full)
}

/// The polar range of a piece with corners `d`, as atan2(rho, z): the
/// largest angle is at a corner, the smallest at a corner or inside an
/// edge's great-circle arc. (f32 acos(z) is off by up to sqrt(2 eps) near
/// the pole, 0.03 rows at R_phi = 512 and more above, which no small margin
/// covers.)
///
/// Candidates are compared in f64 by z |z| / |v|^2 (the signed squared
/// cosine of the polar angle: it falls as the angle grows, and needs no
/// root), and only the two extremes pay for an atan2, in f32 from f64
/// components: within 1e-7 rad, against a margin of 1.2e-4 rad at 128
/// rows and 7.7e-6 at 2048. (This was a third of a big scene's bounds.)
/// The corners are not at the centre (see [`cell_bounds`]).
fn polar_range(d: &[Vec3; 4]) -> (f64, f64) {
    let w = d.map(|c| c.as_dvec3());
    let key = |v: glam::DVec3| v.z * v.z.abs() / v.length_squared();
    // The candidates nearest the pole and nearest the horizon (or below it).
    let (mut top, mut bottom) = ((key(w[0]), w[0]), (key(w[0]), w[0]));
    for k in 0..4 {
        let kk = key(w[k]);
        if kk > top.0 {
            top = (kk, w[k]);
        }
        if kk < bottom.0 {
            bottom = (kk, w[k]);
        }
        // The edge's great circle (normal m) is highest at the direction
        // q of the pole projected on its plane; it counts if it lies on
        // the arc. Scaled by |m|^2 (signs and directions do not change),
        // the test needs no root.
        let b = w[(k + 1) % 4];
        let m = w[k].cross(b);
        let m2 = m.length_squared();
        if m2 > 1e-24 * w[k].length_squared() * b.length_squared() {
            let q = glam::DVec3::Z * m2 - m * m.z;
            let q2 = q.length_squared();
            if q2 > 1e-24 * m2 * m2 && w[k].cross(q).dot(m) >= 0.0 && q.cross(b).dot(m) >= 0.0 {
                let kq = key(q);
                if kq > top.0 {
                    top = (kq, q);
                }
            }
        }
    }
    polar_extremes(top.1, bottom.1)
}

/// The polar range from its candidates nearest the pole (`top`) and nearest
/// the horizon (`bottom`), as atan2(rho, z) in f32 from f64 components.
fn polar_extremes(top: glam::DVec3, bottom: glam::DVec3) -> (f64, f64) {
    let polar = |v: glam::DVec3| {
        f64::from(crate::numeric::atan2_f32(
            (v.x * v.x + v.y * v.y).sqrt() as f32,
            v.z as f32,
        ))
    };
    (
        polar(top).min(std::f64::consts::FRAC_PI_2),
        polar(bottom).max(0.0),
    )
}

/// Rectangles grow by this many cells to absorb rounding.
const RECT_MARGIN: f32 = 0.01;

/// Bounds, in cells, of the projection of a convex planar quad (a triangle
/// repeats a corner) whose corners `d` are given in the shooter's frame
/// (z = normal, relative to the hemisphere centre). `None` when no cell centre
/// can see it: it lies on or below the tangent plane, or falls between cell centres.
///
/// Azimuth: a convex piece that holds neither pole spans less than pi, and its
/// extreme azimuths are at corners, so the smallest arc holding every corner
/// bounds it; a wider span means a pole is inside and every column is taken.
/// Polar angle: the largest is at a corner (or clipped at the horizon); the
/// smallest at a corner or inside an edge's great-circle arc.
pub fn cell_bounds(d: &[Vec3; 4], res: Resolution, far: f32) -> Option<CellRect> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, just tested.
        return unsafe { lanes::cell_bounds(d, res, far) };
    }
    cell_bounds_scalar(d, res, far)
}

/// [`cell_bounds`], one corner and one edge at a time.
pub(super) fn cell_bounds_scalar(d: &[Vec3; 4], res: Resolution, far: f32) -> Option<CellRect> {
    let zmax = d.iter().fold(f32::MIN, |m, c| m.max(c.z));
    if zmax <= 1e-6 * far {
        return None;
    }
    let mut u = [Vec3::Z; 4];
    for k in 0..4 {
        let len = d[k].length();
        if len < 1e-7 * far {
            return Some(whole_hemisphere(res));
        }
        u[k] = d[k] / len;
    }
    let azimuth = azimuth_range(&u);
    let (phi_min, phi_max) = polar_range(d);
    rect_of(res, azimuth, (phi_min as f32, phi_max as f32))
}

/// The rectangle of every cell: a piece with a corner at the centre may
/// fill the hemisphere.
fn whole_hemisphere(res: Resolution) -> CellRect {
    CellRect {
        x0: 0.0,
        x1: res.cols as f32,
        y0: 0.0,
        y1: res.rows as f32,
    }
}

/// The cell rectangle of a piece whose azimuth range is `(t0, span, full)`
/// ([`azimuth_range`]) and polar range `(phi_min, phi_max)`
/// ([`polar_range`]), or `None` where it holds no cell centre.
fn rect_of(
    res: Resolution,
    (t0, span, full): (f32, f32, bool),
    (phi_min, phi_max): (f32, f32),
) -> Option<CellRect> {
    use std::f32::consts::{FRAC_PI_2 as HALF_PI, TAU};
    let (rows, cols) = (res.rows as f32, res.cols as f32);
    let phi_max = phi_max.min(HALF_PI);
    let y1 = phi_max / HALF_PI * rows + RECT_MARGIN;
    let (x0, x1, y0) = if full {
        (0.0, cols, 0.0)
    } else {
        (
            t0 / TAU * cols - RECT_MARGIN,
            (t0 + span) / TAU * cols + RECT_MARGIN,
            phi_min / HALF_PI * rows - RECT_MARGIN,
        )
    };
    // Does any cell centre (i + 0.5) fall inside, along each axis?
    let holds_centre = |lo: f32, hi: f32| (lo - 0.5).ceil() <= (hi - 0.5).floor();
    if !holds_centre(y0.max(0.0), y1.min(rows)) || !holds_centre(x0, x1) {
        return None;
    }
    Some(CellRect { x0, x1, y0, y1 })
}

/// [`cell_bounds`] with the four corners (and the four edges) in SIMD
/// lanes: the same operations lane by lane, so the same rectangle bit for
/// bit (tested), and the choices of extreme corners made by masks instead
/// of branches, which went either way at random (this was a fifth of the
/// bounds of the 4096-cube room's shot).
#[cfg(target_arch = "x86_64")]
pub(super) mod lanes {
    use super::{rect_of, whole_hemisphere, CellRect, Resolution};
    use glam::Vec3;
    use std::arch::x86_64::*;

    /// See [`super::cell_bounds`].
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub(in crate::hemisphere) unsafe fn cell_bounds(
        d: &[Vec3; 4],
        res: Resolution,
        far: f32,
    ) -> Option<CellRect> {
        use std::f32::consts::{PI, TAU};
        let zmax = d.iter().fold(f32::MIN, |m, c| m.max(c.z));
        if zmax <= 1e-6 * far {
            return None;
        }
        let x = _mm_setr_ps(d[0].x, d[1].x, d[2].x, d[3].x);
        let y = _mm_setr_ps(d[0].y, d[1].y, d[2].y, d[3].y);
        let z = _mm_setr_ps(d[0].z, d[1].z, d[2].z, d[3].z);
        // Azimuth, as `azimuth_range` (glam's length: (x x + y y) + z z).
        let squares = _mm_add_ps(
            _mm_add_ps(_mm_mul_ps(x, x), _mm_mul_ps(y, y)),
            _mm_mul_ps(z, z),
        );
        let len = _mm_sqrt_ps(squares);
        if _mm_movemask_ps(_mm_cmplt_ps(len, _mm_set1_ps(1e-7 * far))) != 0 {
            return Some(whole_hemisphere(res));
        }
        let (ux, uy) = (_mm_div_ps(x, len), _mm_div_ps(y, len));
        let on_axis = _mm_cmplt_ps(
            _mm_add_ps(_mm_mul_ps(ux, ux), _mm_mul_ps(uy, uy)),
            _mm_set1_ps(1e-12),
        );
        let mut full = _mm_movemask_ps(on_axis) != 0;
        let wrap = |a: __m128| {
            let below = _mm_cmplt_ps(a, _mm_setzero_ps());
            _mm_blendv_ps(a, _mm_add_ps(a, _mm_set1_ps(TAU)), below)
        };
        let a = wrap(crate::numeric::lanes::atan2_f32(uy, ux));
        // Lane k: the largest wrap(a_j - a_k) (max is exact: the order of
        // the j does not matter; a signed zero changes nothing below).
        let mut widest = _mm_max_ps(_mm_setzero_ps(), wrap(_mm_sub_ps(a, a)));
        for other in [
            _mm_shuffle_ps::<0b00_11_10_01>(a, a),
            _mm_shuffle_ps::<0b01_00_11_10>(a, a),
            _mm_shuffle_ps::<0b10_01_00_11>(a, a),
        ] {
            widest = _mm_max_ps(widest, wrap(_mm_sub_ps(other, a)));
        }
        // The first corner with the narrowest arc, if narrower than a turn.
        let narrowest = {
            let m = _mm_min_ps(widest, _mm_shuffle_ps::<0b01_00_11_10>(widest, widest));
            _mm_min_ps(m, _mm_shuffle_ps::<0b10_11_00_01>(m, m))
        };
        let first = _mm_movemask_ps(_mm_cmpeq_ps(widest, narrowest)).trailing_zeros() as usize;
        let (mut spans, mut starts) = ([0.0f32; 4], [0.0f32; 4]);
        _mm_storeu_ps(spans.as_mut_ptr(), widest);
        _mm_storeu_ps(starts.as_mut_ptr(), a);
        let (t0, span) = if spans[first & 3] < TAU {
            (starts[first & 3], spans[first & 3])
        } else {
            (0.0, TAU)
        };
        if span >= 0.999 * PI {
            full = true;
        }
        let polar = polar_range(x, y, z);
        rect_of(res, (t0, span, full), (polar.0 as f32, polar.1 as f32))
    }

    /// `polar_range` over the corners in lanes `x`, `y`, `z`: every
    /// corner's and edge's candidate at once in f64 lanes, the same
    /// operations as the scalar one's, and its choices (the first of the
    /// highest in the order corner 0, edge 0, corner 1, ..., the first of
    /// the lowest corners) made by masks.
    #[target_feature(enable = "avx2")]
    unsafe fn polar_range(x: __m128, y: __m128, z: __m128) -> (f64, f64) {
        let (wx, wy, wz) = (_mm256_cvtps_pd(x), _mm256_cvtps_pd(y), _mm256_cvtps_pd(z));
        let (mul, add, sub) = (_mm256_mul_pd, _mm256_add_pd, _mm256_sub_pd);
        let dot = |a: [__m256d; 3], b: [__m256d; 3]| {
            add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]))
        };
        // glam's cross.
        let cross = |a: [__m256d; 3], b: [__m256d; 3]| {
            [
                sub(mul(a[1], b[2]), mul(b[1], a[2])),
                sub(mul(a[2], b[0]), mul(b[2], a[0])),
                sub(mul(a[0], b[1]), mul(b[0], a[1])),
            ]
        };
        let abs = |v: __m256d| _mm256_andnot_pd(_mm256_set1_pd(-0.0), v);
        let key = |vz: __m256d, v2: __m256d| _mm256_div_pd(mul(vz, abs(vz)), v2);
        // Lane k of `next`: corner k + 1's (the edge's far end).
        let next = |v: __m256d| _mm256_permute4x64_pd::<0b00_11_10_01>(v);
        let w = [wx, wy, wz];
        let w2 = dot(w, w);
        let corners = key(wz, w2);
        let b = [next(wx), next(wy), next(wz)];
        let m = cross(w, b);
        let m2 = dot(m, m);
        let tiny = _mm256_set1_pd(1e-24);
        let spans = _mm256_cmp_pd::<_CMP_GT_OQ>(m2, mul(mul(tiny, w2), next(w2)));
        let zero = _mm256_setzero_pd();
        let q = [
            sub(mul(zero, m2), mul(m[0], m[2])),
            sub(mul(zero, m2), mul(m[1], m[2])),
            sub(mul(_mm256_set1_pd(1.0), m2), mul(m[2], m[2])),
        ];
        let q2 = dot(q, q);
        let long = _mm256_cmp_pd::<_CMP_GT_OQ>(q2, mul(mul(tiny, m2), m2));
        let after = _mm256_cmp_pd::<_CMP_GE_OQ>(dot(cross(w, q), m), zero);
        let before = _mm256_cmp_pd::<_CMP_GE_OQ>(dot(cross(q, b), m), zero);
        let on_arc = _mm256_and_pd(_mm256_and_pd(spans, long), _mm256_and_pd(after, before));
        let arcs = _mm256_blendv_pd(_mm256_set1_pd(f64::NEG_INFINITY), key(q[2], q2), on_arc);
        // Horizontal extremes, in every lane.
        let halves = |v: __m256d| _mm256_permute4x64_pd::<0b01_00_11_10>(v);
        let pairs = |v: __m256d| _mm256_permute4x64_pd::<0b10_11_00_01>(v);
        let highest = _mm256_max_pd(corners, arcs);
        let highest = _mm256_max_pd(highest, halves(highest));
        let highest = _mm256_max_pd(highest, pairs(highest));
        let lowest = _mm256_min_pd(corners, halves(corners));
        let lowest = _mm256_min_pd(lowest, pairs(lowest));
        let mask = |v: __m256d| _mm256_movemask_pd(v) as u32;
        // Corner k is candidate 2k, edge k's arc candidate 2k + 1.
        let spread = |b: u32| (b & 1) | (b & 2) << 1 | (b & 4) << 2 | (b & 8) << 3;
        let top_corners = mask(_mm256_cmp_pd::<_CMP_EQ_OQ>(corners, highest));
        let top_arcs = mask(_mm256_and_pd(
            _mm256_cmp_pd::<_CMP_EQ_OQ>(arcs, highest),
            on_arc,
        ));
        let top = (spread(top_corners) | spread(top_arcs) << 1).trailing_zeros() as usize;
        let bottom = mask(_mm256_cmp_pd::<_CMP_EQ_OQ>(corners, lowest)).trailing_zeros() as usize;
        let lanes = |v: __m256d| {
            let mut out = [0.0f64; 4];
            _mm256_storeu_pd(out.as_mut_ptr(), v);
            out
        };
        let (cx, cy, cz) = (lanes(wx), lanes(wy), lanes(wz));
        let (qx, qy, qz) = (lanes(q[0]), lanes(q[1]), lanes(q[2]));
        let (k, t) = ((top / 2) & 3, top & 1 == 1);
        let top = if t {
            glam::DVec3::new(qx[k], qy[k], qz[k])
        } else {
            glam::DVec3::new(cx[k], cy[k], cz[k])
        };
        let k = bottom & 3;
        let bottom = glam::DVec3::new(cx[k], cy[k], cz[k]);
        // `polar_extremes`, both angles in lanes.
        let (x, y) = (_mm_setr_pd(top.x, bottom.x), _mm_setr_pd(top.y, bottom.y));
        let rho = _mm_sqrt_pd(_mm_add_pd(_mm_mul_pd(x, x), _mm_mul_pd(y, y)));
        let z = _mm_setr_pd(top.z, bottom.z);
        let angles = crate::numeric::lanes::atan2_f32(_mm_cvtpd_ps(rho), _mm_cvtpd_ps(z));
        let mut out = [0.0f32; 4];
        _mm_storeu_ps(out.as_mut_ptr(), angles);
        (
            f64::from(out[0]).min(std::f64::consts::FRAC_PI_2),
            f64::from(out[1]).max(0.0),
        )
    }
}
