//! Drawing a hemisphere, apart from any device: every polygon's
//! rasterisation proxies and the conservative cell rectangles a shot draws
//! ([`proxies`]: bounds, the walks over the polygons, the ranks' deal of the
//! bounds, the occlusion cull over them), and [`DrawCells`], the one way a
//! shot's rectangles become an item buffer, with two implementations: the
//! device's (`gpu::HemisphereRasterizer`'s device objects, the shader's
//! per-cell test) and the CPU's ([`software::Software`], the same test,
//! eight cells side by side). No wgpu here.

pub mod proxies;
pub mod software;

pub use proxies::{Agree, Instance, ProxyShapes, Scatter};

use crate::hemisphere::TileLayout;
use std::time::Duration;

/// What a shot asks of whoever draws its cells.
#[derive(Clone, Copy)]
pub struct CellShot<'a> {
    /// The rectangles, in drawing order (ties go to the first drawn).
    pub instances: &'a [Instance],
    /// Farther than any distance in the scene.
    pub far: f32,
    /// The tiles and the rank grid.
    pub layout: &'a TileLayout,
    /// This rank's place in the grid.
    pub own: (u32, u32),
    /// 1 x 1 tiles over several ranks: only this rank's cells, packed.
    pub lattice: bool,
    /// Count every element's covered cells, hidden or not (the hybrid form
    /// factors' visibility denominator).
    pub coverage: bool,
    /// With `coverage`, where this rank draws every cell: pack each count
    /// with the element's visible cells (where the drawing can).
    pub pack_visible: bool,
}

/// What a drawing took, and whether its coverage counts carry the visible
/// cells (visible << 32 | covered, as `formfactor::unpack` reads them).
#[derive(Clone, Copy, Debug, Default)]
pub struct DrawTimes {
    /// Drawing (on the device: until the first row could be read).
    pub rasterise: Duration,
    /// Reading the item buffer back (none on the CPU).
    pub readback: Duration,
    /// Whether the coverage pairs are packed with the visible cells.
    pub packed: bool,
}

/// Who draws a shot's cells: fills `items` (row-major, rows x cols; cells
/// other ranks own stay `hemisphere::EMPTY`) with the element each cell
/// sees and, when the shot asks, `coverage` with every covered element's
/// count in element order. The device and the CPU give the same cells for
/// the same rectangles (`tests/suite/rasterisers.rs`).
pub trait DrawCells {
    /// What a draw needs besides the shot (the device: a device and a queue).
    type Context<'c>;
    /// Why a draw failed.
    type Error;

    /// Draws `shot` into `items` and `coverage`.
    fn draw(
        &mut self,
        context: Self::Context<'_>,
        shot: &CellShot<'_>,
        items: &mut Vec<u32>,
        coverage: &mut Vec<(u32, u64)>,
    ) -> Result<DrawTimes, Self::Error>;
}

impl DrawCells for software::Software {
    type Context<'c> = ();
    type Error = std::convert::Infallible;

    fn draw(
        &mut self,
        (): (),
        shot: &CellShot<'_>,
        items: &mut Vec<u32>,
        coverage: &mut Vec<(u32, u64)>,
    ) -> Result<DrawTimes, Self::Error> {
        let start = std::time::Instant::now();
        let threads = crate::parallel::cores().min(8);
        let counts = shot.coverage.then_some(coverage);
        let visible = shot.pack_visible && shot.layout.ranks() == 1;
        let packed = self.draw_shot(shot, threads, items, counts, visible);
        Ok(DrawTimes {
            rasterise: start.elapsed(),
            readback: Duration::ZERO,
            packed,
        })
    }
}
