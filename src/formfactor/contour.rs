//! Lambert's contour integral from a point to a polygon (four edge terms
//! at a time in AVX2 lanes where the CPU has it, bit for bit the scalar
//! terms), and the 2 x 2 Gauss rule that replaces it far from the shooter.

use super::*;

/// Receivers farther than this many shooter radii from its centre take
/// [`GaussQuad`]'s form factor instead of the contour integral: there its
/// error is below 1e-4 of A / (pi d^2), the largest form factor a patch of
/// area A can have at distance d (7e-5 the worst over 20 000 random quads
/// and receivers: `gauss_rule_is_within_its_bound_of_the_contour`).
pub const GAUSS_FAR: f64 = 8.0;

/// A planar quad's 2 x 2 Gauss-Legendre rule over its bilinear map: the
/// form factor from a far differential area to it as four point-to-point
/// kernels, without the contour integral's arctangents (most of a big
/// scene's receivers are many patch sizes away from the shooter). The
/// error falls as (R / d)^4.
#[derive(Clone, Copy, Debug)]
pub struct GaussQuad {
    /// The four points and their weights (a quarter of the map's Jacobian
    /// there, so the weights sum to about the area).
    points: [DVec3; 4],
    weights: [f64; 4],
    /// The quad's unit normal and its corners.
    normal: DVec3,
    corners: [DVec3; 4],
}

impl GaussQuad {
    /// The rule of the planar quad `c` (corners in order) with unit normal `n`.
    pub fn new(c: &[DVec3; 4], n: DVec3) -> Self {
        let g = 0.5 / 3f64.sqrt();
        let nodes = [0.5 - g, 0.5 + g];
        let mut points = [DVec3::ZERO; 4];
        let mut weights = [0.0; 4];
        for (k, (u, v)) in [(0, 0), (1, 0), (0, 1), (1, 1)].into_iter().enumerate() {
            let (u, v) = (nodes[u], nodes[v]);
            points[k] = c[0] * (1.0 - u) * (1.0 - v)
                + c[1] * u * (1.0 - v)
                + c[2] * u * v
                + c[3] * (1.0 - u) * v;
            let du = (c[1] - c[0]) * (1.0 - v) + (c[2] - c[3]) * v;
            let dv = (c[3] - c[0]) * (1.0 - u) + (c[2] - c[1]) * u;
            weights[k] = 0.25 * du.cross(dv).length();
        }
        Self {
            points,
            weights,
            normal: n,
            corners: *c,
        }
    }

    /// The form factor from a differential area at `x` with unit normal `n`
    /// to the quad; `None` where part of the quad lies behind the receiver
    /// (the contour integral clips it). Like the contour integral it takes
    /// no side: receivers behind the quad are the caller's to leave out.
    pub fn form_factor(&self, x: DVec3, n: DVec3) -> Option<f64> {
        if self.corners.iter().any(|&p| n.dot(p - x) < 0.0) {
            return None;
        }
        // The source's cosine times distance is the same for every point
        // of a plane: its height above it.
        let h = self.normal.dot(x - self.corners[0]).abs();
        let mut sum = 0.0;
        for (p, w) in self.points.iter().zip(self.weights) {
            let r = *p - x;
            let r2 = r.length_squared();
            sum += w * n.dot(r) / (r2 * r2);
        }
        Some(sum * h / std::f64::consts::PI)
    }
}

/// Form factor from a differential area at `x` with unit normal `n` to the
/// planar polygon `poly` (any winding), the polygon first clipped to the
/// half-space in front of the receiver (n . (p - x) >= 0):
///
/// F = (1 / 2 pi) sum_k beta_k n . (r_k x r_(k+1)) / |r_k x r_(k+1)|,
///
/// with r_k = p_k - x and beta_k the angle between r_k and r_(k+1). Exact for
/// an unoccluded polygon; 0 when nothing of it is in front of the receiver.
pub fn point_to_polygon(x: DVec3, n: DVec3, poly: &[DVec3]) -> f64 {
    if let [p0, p1, p2, p3] = poly {
        let r = [*p0 - x, *p1 - x, *p2 - x, *p3 - x];
        if r.iter().all(|a| n.dot(*a) >= 0.0) {
            // A quad wholly in front (most calls): nothing to clip, and its
            // four edges side by side (`quad_edge_terms`). The same terms,
            // summed in the same order as below.
            let t = quad_edge_terms(&r, n);
            let sum = 0.0 + t[0] + t[1] + t[2] + t[3];
            return (sum / (2.0 * std::f64::consts::PI)).abs();
        }
    }
    let mut clipped = [DVec3::ZERO; 8];
    let mut len = 0;
    let count = poly.len().min(6);
    for k in 0..count {
        let (a, b) = (poly[k] - x, poly[(k + 1) % count] - x);
        let (da, db) = (n.dot(a), n.dot(b));
        if da >= 0.0 {
            clipped[len] = a;
            len += 1;
        }
        if (da >= 0.0) != (db >= 0.0) {
            let t = da / (da - db);
            clipped[len] = a + (b - a) * t;
            len += 1;
        }
    }
    // Four edges at a time ([`edge_terms`]: half of the 4096-cube room's
    // calls clip, mostly corners a rounding behind the receiver's plane),
    // summed in edge order as one by one.
    let mut sum = 0.0;
    for first in (0..len).step_by(4) {
        let (mut a, mut b) = ([DVec3::ZERO; 4], [DVec3::ZERO; 4]);
        let edges = (len - first).min(4);
        for l in 0..edges {
            a[l] = clipped[first + l];
            b[l] = clipped[(first + l + 1) % len];
        }
        let t = edge_terms(&a, &b, n);
        for term in &t[..edges] {
            sum += term;
        }
    }
    (sum / (2.0 * std::f64::consts::PI)).abs()
}

/// The four edge terms of a quad `r` (corners relative to the point) seen
/// from a point with normal `n`, in edge order. Where the CPU has AVX2 the
/// four go side by side ([`edge_terms`]), with the same bits.
#[inline]
pub(super) fn quad_edge_terms(r: &[DVec3; 4], n: DVec3) -> [f64; 4] {
    edge_terms(r, &[r[1], r[2], r[3], r[0]], n)
}

/// [`edge_term`] of the four edges `a[k]`-`b[k]`, side by side where the
/// CPU has AVX2 ([`edge_terms_avx2`]), with the same bits.
#[inline]
pub(super) fn edge_terms(a: &[DVec3; 4], b: &[DVec3; 4], n: DVec3) -> [f64; 4] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, just tested.
        return unsafe { edge_terms_avx2(a, b, n) };
    }
    [0, 1, 2, 3].map(|k| edge_term(a[k], b[k], n))
}

/// [`edge_term`] of the four edges `a[k]`-`b[k]`, one a lane: glam's cross
/// and dot products and [`crate::numeric::lanes::atan2`], the same
/// operations in the same order.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn edge_terms_avx2(a: &[DVec3; 4], b: &[DVec3; 4], n: DVec3) -> [f64; 4] {
    use std::arch::x86_64::*;
    let lanes = |r: &[DVec3; 4], f: fn(&DVec3) -> f64| {
        let v = [0, 1, 2, 3].map(|k| f(&r[k]));
        _mm256_loadu_pd(v.as_ptr())
    };
    let (ax, ay, az) = (lanes(a, |v| v.x), lanes(a, |v| v.y), lanes(a, |v| v.z));
    let (bx, by, bz) = (lanes(b, |v| v.x), lanes(b, |v| v.y), lanes(b, |v| v.z));
    let (mul, sub, add) = (
        |a, b| _mm256_mul_pd(a, b),
        |a, b| _mm256_sub_pd(a, b),
        |a, b| _mm256_add_pd(a, b),
    );
    // c = a x b: (a.y b.z - b.y a.z, a.z b.x - b.z a.x, a.x b.y - b.x a.y).
    let cx = sub(mul(ay, bz), mul(by, az));
    let cy = sub(mul(az, bx), mul(bz, ax));
    let cz = sub(mul(ax, by), mul(bx, ay));
    let dot = |x1, y1, z1, x2, y2, z2| add(add(mul(x1, x2), mul(y1, y2)), mul(z1, z2));
    let lc = _mm256_sqrt_pd(dot(cx, cy, cz, cx, cy, cz));
    let ab = dot(ax, ay, az, bx, by, bz);
    let (nx, ny, nz) = (
        _mm256_set1_pd(n.x),
        _mm256_set1_pd(n.y),
        _mm256_set1_pd(n.z),
    );
    let nc = dot(nx, ny, nz, cx, cy, cz);
    let angle = crate::numeric::lanes::atan2(lc, ab);
    let term = _mm256_div_pd(mul(angle, nc), lc);
    // A zero-length edge, or one through the point: nothing.
    let none = _mm256_cmp_pd::<_CMP_LE_OQ>(lc, _mm256_set1_pd(1e-300));
    let term = _mm256_blendv_pd(term, _mm256_setzero_pd(), none);
    let mut out = [0.0; 4];
    _mm256_storeu_pd(out.as_mut_ptr(), term);
    out
}

/// One edge's term of [`point_to_polygon`]'s sum: the angle between `a` and
/// `b` times n . (a x b) / |a x b|.
#[inline(always)]
pub(super) fn edge_term(a: DVec3, b: DVec3, n: DVec3) -> f64 {
    let c = a.cross(b);
    let lc = c.length();
    // A zero-length edge, or an edge through x (its plane is undefined and
    // the point lies on the polygon's boundary): it contributes nothing.
    if lc <= 1e-300 {
        return 0.0;
    }
    crate::numeric::atan2(lc, a.dot(b)) * n.dot(c) / lc
}

/// The largest distance from `centre` to a corner of `e`.
pub(super) fn element_radius(e: &crate::mesh::Element, centre: DVec3) -> f64 {
    e.corners
        .iter()
        .map(|c| c.as_dvec3().distance(centre))
        .fold(0.0, f64::max)
}

/// Four points standing for equal parts of an element: the centres of the
/// quarters of a quad (bilinear u, v in {1/4, 3/4}) or of the four midpoint
/// triangles of a triangle.
pub(super) fn sub_points(e: &crate::mesh::Element) -> [DVec3; 4] {
    let c = e.corners.map(|p| p.as_dvec3());
    if e.corners[3] == e.corners[2] {
        let (m01, m12, m20) = (
            (c[0] + c[1]) / 2.0,
            (c[1] + c[2]) / 2.0,
            (c[2] + c[0]) / 2.0,
        );
        [
            (c[0] + m01 + m20) / 3.0,
            (c[1] + m12 + m01) / 3.0,
            (c[2] + m20 + m12) / 3.0,
            (m01 + m12 + m20) / 3.0,
        ]
    } else {
        let at = |u: f64, v: f64| {
            c[0] * (1.0 - u) * (1.0 - v)
                + c[1] * u * (1.0 - v)
                + c[2] * u * v
                + c[3] * (1.0 - u) * v
        };
        [
            at(0.25, 0.25),
            at(0.75, 0.25),
            at(0.75, 0.75),
            at(0.25, 0.75),
        ]
    }
}

/// The distinct corners of an outline that repeats its last corner for a triangle.
pub fn outline(corners: &[glam::Vec3; 4]) -> ([DVec3; 4], usize) {
    let c = corners.map(|p| p.as_dvec3());
    let n = if corners[3] == corners[2] { 3 } else { 4 };
    (c, n)
}
