//! Sampling shared by the CPU's light estimates: points on triangles and
//! quads, uniform numbers from the project's seeded generator, and a
//! deterministic parallel map (each slot's result depends only on its index).

use crate::rng::Rng;
use glam::Vec3;

/// Where shadow rays start: a point just off a surface (`origin`), the
/// surface's normal there, and its polygon (which the rays skip).
#[derive(Clone, Copy)]
pub struct RayStart {
    /// The point, moved off its surface along the normal.
    pub origin: Vec3,
    /// The surface's normal.
    pub normal: Vec3,
    /// The surface's polygon.
    pub polygon: u32,
}

/// Points per element along each axis for its mean irradiance, from lights
/// and from emitting surfaces alike: the element means are taken out of the
/// interpolated rest, so their noise would show as blotches.
pub const ELEMENT_POINTS: u32 = 4;

/// A point of a triangle or convex quad from (u, v) in the unit square, and
/// the density's Jacobian there (area per unit (u, v)): bilinear for a quad,
/// the square folded onto a triangle for a triangle.
pub fn point_in(c: &[Vec3], u: f32, v: f32) -> (Vec3, f32) {
    if c.len() == 3 {
        let (u, v) = if u + v > 1.0 {
            (1.0 - u, 1.0 - v)
        } else {
            (u, v)
        };
        let (e1, e2) = (c[1] - c[0], c[2] - c[0]);
        // The folded square covers the triangle once: area per unit (u, v)
        // is the triangle's area.
        (c[0] + e1 * u + e2 * v, 0.5 * e1.cross(e2).length())
    } else {
        let p = c[0] * (1.0 - u) * (1.0 - v)
            + c[1] * u * (1.0 - v)
            + c[2] * u * v
            + c[3] * (1.0 - u) * v;
        let du = (c[1] - c[0]) * (1.0 - v) + (c[2] - c[3]) * v;
        let dv = (c[3] - c[0]) * (1.0 - u) + (c[2] - c[1]) * u;
        (p, du.cross(dv).length())
    }
}

/// Which cells of a `grid` x `grid` stratification of a unit square (an
/// emitter's (u, v), the hemisphere's directions) a point's rays take: the
/// `side` x `side` block from `first`.
#[derive(Clone, Copy, Debug)]
pub struct Strata {
    /// Cells along each axis of the whole stratification.
    pub grid: u32,
    /// The block's first cell.
    pub first: [u32; 2],
    /// The block's cells along each axis.
    pub side: u32,
}

impl Strata {
    /// Every cell of a `side` x `side` grid.
    pub fn whole(side: u32) -> Self {
        Strata {
            grid: side,
            first: [0, 0],
            side,
        }
    }
}

/// A cosine-distributed direction about `normal` (unit) from two uniform
/// numbers; `tangent` is any unit vector across the normal.
pub fn cosine_direction(normal: Vec3, tangent: Vec3, u1: f32, u2: f32) -> Vec3 {
    let bitangent = normal.cross(tangent);
    let r = u1.sqrt();
    let phi = std::f32::consts::TAU * u2;
    let z = (1.0 - u1).max(0.0).sqrt();
    (tangent * (r * phi.cos()) + bitangent * (r * phi.sin()) + normal * z).normalize()
}

/// A uniform number in [0, 1).
pub fn unit(rng: &mut Rng) -> f32 {
    (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32
}

/// Runs `work(index, slot)` over every slot, on every core; each slot's
/// result depends only on its index, so the output is the same on any
/// number of threads.
pub fn in_parallel<T: Send>(out: &mut [T], work: impl Fn(usize, &mut T) + Sync) {
    let threads = crate::parallel::cores();
    if threads <= 1 || out.len() <= 1 {
        // One core (a rank pinned to its own): no thread to start for it,
        // here once a shot and once a run of a transport's rays.
        for (k, slot) in out.iter_mut().enumerate() {
            work(k, slot);
        }
        return;
    }
    let chunk = out.len().div_ceil(threads * 8).max(1);
    let next = std::sync::Mutex::new(out.chunks_mut(chunk).enumerate());
    let worker = || loop {
        let item = next.lock().map(|mut it| it.next()).ok().flatten();
        let Some((c, slots)) = item else { break };
        for (k, slot) in slots.iter_mut().enumerate() {
            work(c * chunk + k, slot);
        }
    };
    // The calling thread is one of the workers.
    crate::parallel::scope(|s| {
        for _ in 1..threads {
            s.spawn(move |_| worker());
        }
        worker();
    });
}
