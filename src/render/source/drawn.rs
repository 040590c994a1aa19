//! Rows drawn outside a shot, for `render::ahead`: which shooters need a
//! drawing at all, a row drawn whole by a source of one process, and the
//! timings of a source that drew beside this one.

use super::{GpuFormFactors, PhaseTimes, Shared};
use crate::formfactor::Row;
use crate::gpu::Gpu;
use crate::lit_mesh::LitMesh;
use crate::parallel::Single;
use crate::render::cache::RowKey;
use crate::render::options::{RenderError, RenderOptions};
use std::sync::Arc;
use std::time::Instant;

/// What a sibling source is built from (see [`GpuFormFactors::parts`]).
pub(in crate::render) struct Parts<'a> {
    gpu: &'a Gpu,
    mesh: &'a LitMesh,
    extent: f32,
    shared: Shared,
}

impl<'a> GpuFormFactors<'a> {
    /// What a sibling source needs to be built alike
    /// ([`GpuFormFactors::sibling`]).
    pub(in crate::render) fn parts(&self) -> Parts<'a> {
        Parts {
            gpu: self.gpu,
            mesh: self.mesh,
            extent: self.extent,
            shared: Shared {
                shapes: Arc::clone(&self.shapes),
                receivers: Arc::clone(&self.receivers),
                guide_leaves: Arc::clone(&self.guide_leaves),
            },
        }
    }

    /// A source of one process (`one`) built like the one `parts` came
    /// from, sharing its read-only parts.
    pub(in crate::render) fn sibling(
        parts: Parts<'a>,
        opts: &RenderOptions,
        one: &'a Single,
    ) -> Result<Self, RenderError> {
        Self::sharing(
            (parts.gpu, parts.mesh),
            opts,
            one,
            parts.extent,
            parts.shared,
        )
    }

    /// The key of the row a shot of `shooter` at `centre` with unshot power
    /// `power` would draw, or `None` when it would draw nothing (a transport
    /// row, or one in this source's cache).
    pub(in crate::render) fn drawn_key(
        &self,
        shooter: u32,
        centre: glam::Vec3,
        power: f64,
    ) -> Option<RowKey> {
        if self.choice.by_transport(power) {
            return None;
        }
        let key = RowKey::new(shooter, centre, self.tier_at(shooter, power));
        self.cache.get(&key).is_none().then_some(key)
    }

    /// The row `key` names, drawn here at `centre` (a source of one process
    /// draws the whole hemisphere), before or beside the shot that takes
    /// it: the same row as a shot would draw, since a row depends only on
    /// the shooter, its centre and the tier. Its time counts as summing.
    pub(in crate::render) fn draw_row(
        &mut self,
        key: RowKey,
        centre: glam::Vec3,
    ) -> Result<Row, RenderError> {
        let start = Instant::now();
        let before = self.timings.drawing();
        let (row, exchange) = self.fresh_row(key.patch, centre, usize::from(key.tier))?;
        let drawn = self.timings.drawing() - before;
        self.timings.exchange += exchange;
        self.timings.sum += start.elapsed().saturating_sub(exchange + drawn);
        Ok(row)
    }

    /// The row `key` names for the shot under way, drawn here at `centre`,
    /// and the time spent in exchanges (the shot's own timing counts it).
    pub(in crate::render) fn own_row(
        &mut self,
        key: RowKey,
        centre: glam::Vec3,
    ) -> Result<(Row, std::time::Duration), RenderError> {
        self.fresh_row(key.patch, centre, usize::from(key.tier))
    }

    /// Adds what a sibling source spent (its phases and counts) to this
    /// one's, so the report's phases count every row drawn.
    pub(in crate::render) fn absorb(&mut self, other: &PhaseTimes) {
        let t = &mut self.timings;
        t.bounds += other.bounds;
        t.rasterise += other.rasterise;
        t.read_back += other.read_back;
        t.exchange += other.exchange;
        t.sum += other.sum;
        t.far += other.far;
        t.far_ahead += other.far_ahead;
        t.rects += other.rects;
        t.occluded += other.occluded;
        t.skipped += other.skipped;
        t.cull_traffic = t.cull_traffic.plus(other.cull_traffic);
        t.rect_traffic = t.rect_traffic.plus(other.rect_traffic);
        t.bounded += other.bounded;
        t.cells += other.cells;
        t.receivers += other.receivers;
        t.split += other.split;
    }
}
