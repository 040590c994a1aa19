//! How far one image is from another, the way the project scores its camera
//! images against path-traced references. Pure maths.

/// Side of the square blocks images are compared over, in pixels.
pub const BLOCK: usize = 4;

/// The symmetric mean absolute percentage error between two images of
/// `width` x `height` linear RGB pixels (top row first), over the interior
/// `BLOCK` x `BLOCK` blocks (the outermost ring of blocks left out): each
/// block's mean per channel, |a - b| / ((|a| + |b|) / 2) per channel (0 where
/// both are 0), averaged over channels and blocks. A fraction (0.025 = 2.5 %).
pub fn smape(a: &[[f32; 3]], b: &[[f32; 3]], width: usize, height: usize) -> f64 {
    let (bw, bh) = (width / BLOCK, height / BLOCK);
    let block = |img: &[[f32; 3]], bx: usize, by: usize| {
        let mut sum = [0.0f64; 3];
        for y in by * BLOCK..(by + 1) * BLOCK {
            for x in bx * BLOCK..(bx + 1) * BLOCK {
                for c in 0..3 {
                    sum[c] += img[y * width + x][c] as f64;
                }
            }
        }
        sum
    };
    let (mut total, mut count) = (0.0, 0usize);
    for by in 1..bh.saturating_sub(1) {
        for bx in 1..bw.saturating_sub(1) {
            let (p, q) = (block(a, bx, by), block(b, bx, by));
            for c in 0..3 {
                let den = (p[c].abs() + q[c].abs()) / 2.0;
                if den > 0.0 {
                    total += (p[c] - q[c]).abs() / den;
                }
                count += 1;
            }
        }
    }
    if count == 0 {
        0.0
    } else {
        total / count as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_uniform_ten_percent_offset_scores_its_smape() {
        let a = vec![[1.0f32; 3]; 16 * 16];
        let b = vec![[1.1f32; 3]; 16 * 16];
        let s = smape(&a, &b, 16, 16);
        assert!((s - 0.1 / 1.05).abs() < 1e-6, "{s}");
        assert_eq!(smape(&a, &a, 16, 16), 0.0);
    }

    #[test]
    fn the_border_ring_is_left_out() {
        let a = vec![[1.0f32; 3]; 16 * 16];
        let mut b = a.clone();
        for p in b.iter_mut().take(16) {
            *p = [9.0; 3];
        }
        assert_eq!(smape(&a, &b, 16, 16), 0.0);
    }
}
