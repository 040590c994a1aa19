//! atan2 and rounding without library calls.
//!
//! On the baseline x86-64 target `f64::atan2`, `f32::atan2` and
//! `f64::round` are calls into libm. A shot rounds every receiver's form
//! factor and every patch's unshot power to fixed point ([`round_u64`],
//! [`round_i64`]: the same results, by truncation and one compare), and a
//! big scene's shot makes millions of atan2 calls: four per contour
//! integral of every receiver (`formfactor::point_to_polygon`) and
//! six per cell rectangle (`hemisphere::cell_bounds`). glibc's are
//! correctly rounded and cost 40-100 cycles; these reduce the argument to
//! [0, 1] with one division and evaluate a polynomial fitted to atan on it
//! (Chebyshev fit of atan(t)/t in t^2, converted to powers): within 5e-14
//! relative in f64 and 5e-7 rad in f32, against std in the tests below.

use std::f32::consts::{FRAC_PI_2 as HALF_PI_32, PI as PI_32};
use std::f64::consts::{FRAC_PI_2, PI};

/// atan(t) / t as a polynomial in t^2, for t in [0, 1] (relative error 4e-14).
const ATAN_64: [f64; 16] = [
    0.999_999_999_999_959_8,
    -0.333_333_333_312_143_54,
    0.199_999_998_147_622_34,
    -0.142_857_078_498_869_03,
    0.111_109_929_433_003_45,
    -0.090_895_865_337_160_51,
    0.076_824_880_410_572_41,
    -0.066_155_618_187_011_77,
    0.056_886_515_129_014_79,
    -0.047_130_499_046_033_995,
    0.035_636_177_429_358_366,
    -0.022_994_407_742_328_905,
    0.011_746_193_147_377_931,
    -0.004_344_535_897_620_449,
    0.001_018_241_070_888_484_8,
    -0.000_112_433_349_210_503_12,
];

/// The same in f32 (absolute error 1.7e-7 on [0, 1]).
const ATAN_32: [f32; 8] = [
    0.999_999_9,
    -0.333_319_6,
    0.199_692_38,
    -0.140_165_97,
    0.099_061_22,
    -0.059_367_374,
    0.024_166_333,
    -0.004_668_801,
];

/// `x.round() as i64` (half away from zero) without a libm call: the same
/// result for every f64, NaN (0) and out-of-range values (saturated) included.
#[inline]
pub fn round_i64(x: f64) -> i64 {
    // From 2^52 up every f64 is an integer (and NaN compares false).
    if x.is_nan() || x.abs() >= 4_503_599_627_370_496.0 {
        return x as i64;
    }
    let t = x as i64;
    // Exact: the fractional part of an f64 below 2^52 is an f64. No
    // branches: which way a value rounds is a coin toss for the predictor.
    let f = x - t as f64;
    t + i64::from(f >= 0.5) - i64::from(f <= -0.5)
}

/// `x.round() as u64` without a libm call: the same result for every f64
/// (negative and NaN give 0, too large saturates).
#[inline]
pub fn round_u64(x: f64) -> u64 {
    if x.is_nan() || x <= 0.0 {
        return 0;
    }
    if x >= 4_503_599_627_370_496.0 {
        return x as u64;
    }
    let t = x as u64;
    t + u64::from(x - t as f64 >= 0.5)
}

/// The polynomial with coefficients `c` (lowest first) at `u`, by Estrin's
/// scheme: four levels of independent products instead of Horner's chain of
/// fifteen dependent ones (no fused multiply-add on the baseline target).
#[inline]
fn estrin_16(c: &[f64; 16], u: f64) -> f64 {
    let u2 = u * u;
    let u4 = u2 * u2;
    let u8 = u4 * u4;
    let p: [f64; 8] = std::array::from_fn(|k| c[2 * k] + c[2 * k + 1] * u);
    let q: [f64; 4] = std::array::from_fn(|k| p[2 * k] + p[2 * k + 1] * u2);
    let r = [q[0] + q[1] * u4, q[2] + q[3] * u4];
    r[0] + r[1] * u8
}

/// An atan2 for one float type: reduce to t = min / max of |x|, |y| in
/// [0, 1], take atan(t) = t p(t^2) from `poly`, and unfold the octant.
macro_rules! atan2_for {
    ($(#[$doc:meta])* $name:ident, $t:ty, $pi:expr, $half_pi:expr, $poly:expr) => {
        $(#[$doc])*
        #[inline]
        pub fn $name(y: $t, x: $t) -> $t {
            let (ax, ay) = (x.abs(), y.abs());
            let (num, den) = if ay <= ax { (ay, ax) } else { (ax, ay) };
            if den == 0.0 {
                let zero: $t = 0.0;
                return if x.is_sign_negative() {
                    $pi.copysign(y)
                } else {
                    zero.copysign(y)
                };
            }
            let t = num / den;
            let mut a = t * ($poly)(t * t);
            if ay > ax {
                a = $half_pi - a;
            }
            if x < 0.0 {
                a = $pi - a;
            }
            a.copysign(y)
        }
    };
}

atan2_for!(
    /// The angle of (x, y) from the x axis in (-pi, pi], as `y.atan2(x)` within
    /// 5e-14 relative; 0 for (0, 0), NaN for NaN input.
    atan2,
    f64,
    PI,
    FRAC_PI_2,
    |u| estrin_16(&ATAN_64, u)
);

atan2_for!(
    /// `y.atan2(x)` in f32, within 5e-7 rad; 0 for (0, 0).
    atan2_f32,
    f32,
    PI_32,
    HALF_PI_32,
    |u| ATAN_32.iter().rev().fold(0.0, |acc, &c| acc * u + c)
);

/// [`atan2`] in four lanes at once, for CPUs with AVX2: the same
/// operations in the same order, lane by lane, so the same bits.
#[cfg(target_arch = "x86_64")]
pub mod lanes {
    use super::{ATAN_64, FRAC_PI_2, PI};
    use std::arch::x86_64::*;

    /// `atan2(y[k], x[k])` in lane k.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub unsafe fn atan2(y: __m256d, x: __m256d) -> __m256d {
        let sign = _mm256_set1_pd(-0.0);
        let (ax, ay) = (_mm256_andnot_pd(sign, x), _mm256_andnot_pd(sign, y));
        // (num, den) = if ay <= ax { (ay, ax) } else { (ax, ay) }
        let low = _mm256_cmp_pd::<_CMP_LE_OQ>(ay, ax);
        let num = _mm256_blendv_pd(ax, ay, low);
        let den = _mm256_blendv_pd(ay, ax, low);
        let t = _mm256_div_pd(num, den);
        let u = _mm256_mul_pd(t, t);
        // Estrin's scheme, as `estrin_16`.
        let u2 = _mm256_mul_pd(u, u);
        let u4 = _mm256_mul_pd(u2, u2);
        let u8 = _mm256_mul_pd(u4, u4);
        let c = |k: usize| _mm256_set1_pd(ATAN_64[k]);
        let p: [__m256d; 8] =
            std::array::from_fn(|k| _mm256_add_pd(c(2 * k), _mm256_mul_pd(c(2 * k + 1), u)));
        let q: [__m256d; 4] =
            std::array::from_fn(|k| _mm256_add_pd(p[2 * k], _mm256_mul_pd(p[2 * k + 1], u2)));
        let r0 = _mm256_add_pd(q[0], _mm256_mul_pd(q[1], u4));
        let r1 = _mm256_add_pd(q[2], _mm256_mul_pd(q[3], u4));
        let poly = _mm256_add_pd(r0, _mm256_mul_pd(r1, u8));
        let mut a = _mm256_mul_pd(t, poly);
        // if ay > ax { a = pi/2 - a }; if x < 0 { a = pi - a }
        let steep = _mm256_cmp_pd::<_CMP_GT_OQ>(ay, ax);
        a = _mm256_blendv_pd(a, _mm256_sub_pd(_mm256_set1_pd(FRAC_PI_2), a), steep);
        let left = _mm256_cmp_pd::<_CMP_LT_OQ>(x, _mm256_setzero_pd());
        a = _mm256_blendv_pd(a, _mm256_sub_pd(_mm256_set1_pd(PI), a), left);
        // den == 0: pi or 0 by the sign of x.
        let zero = _mm256_cmp_pd::<_CMP_EQ_OQ>(den, _mm256_setzero_pd());
        let x_negative = _mm256_castsi256_pd(_mm256_srai_epi64_emulated(_mm256_castpd_si256(x)));
        let edge = _mm256_and_pd(x_negative, _mm256_set1_pd(PI));
        a = _mm256_blendv_pd(a, edge, zero);
        // a.copysign(y)
        _mm256_or_pd(_mm256_andnot_pd(sign, a), _mm256_and_pd(sign, y))
    }

    /// [`super::atan2_f32`] in four lanes at once: the same operations in
    /// the same order, lane by lane, so the same bits.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[target_feature(enable = "avx2")]
    pub unsafe fn atan2_f32(y: __m128, x: __m128) -> __m128 {
        use super::{ATAN_32, HALF_PI_32, PI_32};
        let sign = _mm_set1_ps(-0.0);
        let (ax, ay) = (_mm_andnot_ps(sign, x), _mm_andnot_ps(sign, y));
        let low = _mm_cmple_ps(ay, ax);
        let num = _mm_blendv_ps(ax, ay, low);
        let den = _mm_blendv_ps(ay, ax, low);
        let t = _mm_div_ps(num, den);
        let u = _mm_mul_ps(t, t);
        // Horner's fold from 0, as the scalar one.
        let mut poly = _mm_setzero_ps();
        for &c in ATAN_32.iter().rev() {
            poly = _mm_add_ps(_mm_mul_ps(poly, u), _mm_set1_ps(c));
        }
        let mut a = _mm_mul_ps(t, poly);
        let steep = _mm_cmpgt_ps(ay, ax);
        a = _mm_blendv_ps(a, _mm_sub_ps(_mm_set1_ps(HALF_PI_32), a), steep);
        let left = _mm_cmplt_ps(x, _mm_setzero_ps());
        a = _mm_blendv_ps(a, _mm_sub_ps(_mm_set1_ps(PI_32), a), left);
        // den == 0: pi or 0 by the sign of x.
        let zero = _mm_cmpeq_ps(den, _mm_setzero_ps());
        let x_negative = _mm_castsi128_ps(_mm_srai_epi32::<31>(_mm_castps_si128(x)));
        a = _mm_blendv_ps(a, _mm_and_ps(x_negative, _mm_set1_ps(PI_32)), zero);
        _mm_or_ps(_mm_andnot_ps(sign, a), _mm_and_ps(sign, y))
    }

    /// All ones in the lanes whose sign bit is set (AVX2 has no 64-bit
    /// arithmetic shift).
    #[target_feature(enable = "avx2")]
    unsafe fn _mm256_srai_epi64_emulated(v: __m256i) -> __m256i {
        let high = _mm256_srai_epi32::<31>(v);
        _mm256_shuffle_epi32::<0b11_11_01_01>(high)
    }
}

/// Asks the cache for the line holding `p` (a hint: no effect on results),
/// for loops whose scattered reads are cache misses their few instructions
/// cannot hide.
#[inline(always)]
pub fn prefetch<T>(p: *const T) {
    // SAFETY: a prefetch only hints the cache; it reads nothing and
    // cannot fault, whatever the address.
    #[cfg(target_arch = "x86_64")]
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(p.cast())
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn four_lanes_give_the_angle_bit_for_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        use std::arch::x86_64::*;
        let mut pairs = points();
        for &y in &[0.0, -0.0, 1.0, -1.0, 1e-300, f64::NAN, f64::INFINITY] {
            for &x in &[0.0, -0.0, 1.0, -1.0, 1e-300, f64::NAN, f64::NEG_INFINITY] {
                pairs.push((y, x));
            }
        }
        for chunk in pairs.chunks_exact(4) {
            let (y, x): (Vec<f64>, Vec<f64>) = chunk.iter().copied().unzip();
            let mut got = [0.0f64; 4];
            // SAFETY: the CPU has AVX2, just tested.
            unsafe {
                let v = lanes::atan2(_mm256_loadu_pd(y.as_ptr()), _mm256_loadu_pd(x.as_ptr()));
                _mm256_storeu_pd(got.as_mut_ptr(), v);
            }
            for k in 0..4 {
                let want = atan2(y[k], x[k]);
                assert!(
                    got[k].to_bits() == want.to_bits() || (got[k].is_nan() && want.is_nan()),
                    "atan2({}, {}): {} against {}",
                    y[k],
                    x[k],
                    got[k],
                    want
                );
            }
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn four_f32_lanes_give_the_angle_bit_for_bit() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        use std::arch::x86_64::*;
        let mut pairs: Vec<(f32, f32)> = points()
            .iter()
            .map(|&(y, x)| (y as f32, x as f32))
            .collect();
        for &y in &[0.0, -0.0, 1.0, -1.0, 1e-30, f32::NAN, f32::INFINITY] {
            for &x in &[0.0, -0.0, 1.0, -1.0, 1e-30, f32::NAN, f32::NEG_INFINITY] {
                pairs.push((y, x));
            }
        }
        for chunk in pairs.chunks_exact(4) {
            let (y, x): (Vec<f32>, Vec<f32>) = chunk.iter().copied().unzip();
            let mut got = [0.0f32; 4];
            // SAFETY: the CPU has AVX2, just tested.
            unsafe {
                let v = lanes::atan2_f32(_mm_loadu_ps(y.as_ptr()), _mm_loadu_ps(x.as_ptr()));
                _mm_storeu_ps(got.as_mut_ptr(), v);
            }
            for k in 0..4 {
                let want = atan2_f32(y[k], x[k]);
                assert!(
                    got[k].to_bits() == want.to_bits() || (got[k].is_nan() && want.is_nan()),
                    "atan2_f32({}, {}): {} against {}",
                    y[k],
                    x[k],
                    got[k],
                    want
                );
            }
        }
    }

    /// Points on circles of many radii in every direction, the axes and the
    /// diagonals included.
    fn points() -> Vec<(f64, f64)> {
        let mut out = Vec::new();
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        for k in 0..200_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let angle = (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 * PI - PI;
            let radius = 10f64.powi(k % 13 - 6);
            out.push((radius * angle.sin(), radius * angle.cos()));
        }
        for (y, x) in [
            (0.0, 1.0),
            (1.0, 0.0),
            (0.0, -1.0),
            (-1.0, 0.0),
            (1.0, 1.0),
            (-1.0, -1.0),
        ] {
            out.push((y, x));
        }
        out
    }

    #[test]
    fn the_f64_angle_is_std_within_5e_14_relative() {
        let mut worst = 0.0f64;
        for (y, x) in points() {
            let (got, want) = (atan2(y, x), y.atan2(x));
            worst = worst.max((got - want).abs() / want.abs().max(1e-300));
        }
        assert!(worst < 5e-14, "worst relative error {worst:e}");
        // Small angles keep their relative precision (contour integrals of
        // far polygons sum terms of this size).
        let tiny = atan2(1e-9, 1.0);
        assert!((tiny - 1e-9).abs() < 1e-22, "{tiny:e}");
    }

    #[test]
    fn the_f32_angle_is_std_within_5e_7_rad() {
        let mut worst = 0.0f32;
        for (y, x) in points() {
            let (y, x) = (y as f32, x as f32);
            worst = worst.max((atan2_f32(y, x) - y.atan2(x)).abs());
        }
        assert!(worst < 5e-7, "worst error {worst:e} rad");
    }

    #[test]
    fn rounding_is_std_bit_for_bit() {
        let mut values = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            2.5,
            -2.5,
            0.499_999_999_999_999_94,
            -0.499_999_999_999_999_94,
            4_503_599_627_370_495.5,
            4_503_599_627_370_497.0,
            -4_503_599_627_370_495.5,
            9.3e18,
            2e19,
            -2e19,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MIN_POSITIVE,
        ];
        for (y, x) in points() {
            values.push(y * 1e12);
            values.push(x * 3.7);
            values.push((y * 1e6).floor() + 0.5);
        }
        for v in values {
            assert_eq!(round_i64(v), v.round() as i64, "{v:e}");
            assert_eq!(round_u64(v), v.round() as u64, "{v:e}");
        }
    }

    #[test]
    fn zeros_and_signs_follow_std() {
        for (y, x) in [
            (0.0, 0.0),
            (-0.0, 0.0),
            (0.0, -0.0),
            (-0.0, -0.0),
            (0.0, -2.0),
            (-0.0, -2.0),
        ] {
            assert_eq!(atan2(y, x), f64::atan2(y, x), "({y}, {x})");
            assert_eq!(
                atan2_f32(y as f32, x as f32),
                f32::atan2(y as f32, x as f32)
            );
        }
        assert!(atan2(f64::NAN, 1.0).is_nan());
        assert!(atan2(1.0, f64::NAN).is_nan());
    }
}
