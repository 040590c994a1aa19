//! The hemisphere rasteriser: draws every element as seen from a shooter into
//! an R32Uint item buffer of R_phi rows by R_theta columns (see
//! `shaders/hemisphere.wgsl` for the projection and its traps).
//!
//! Per shot the CPU finds a conservative cell rectangle for each piece the
//! shooter can see (`hemisphere::cell_bounds`: cheap, and it culls everything
//! below the tangent plane before any GPU work) and the piece's edge planes in
//! the shooter's frame; the GPU rasterises the rectangles and tests every cell
//! exactly. Pipelines, buffers and geometry are created once.

use super::target::RenderTarget;
use super::GpuError;
use crate::hemisphere::{Resolution, TileLayout, EMPTY};
use crate::mesh::{Mesh, ShooterFrame};
use crate::raster::proxies::{
    in_view, Agree, Instance, Lookup, Ownership, Proxies, ProxyShapes, Scatter, TilePlace,
};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use std::time::{Duration, Instant};

mod device;
mod tess;
use crate::raster::{CellShot, DrawCells};
use device::{
    buffer, direction_buffer, item_bind_group, item_pipeline, rect_pipeline, DeviceCells,
};
use tess::Tessellation;

/// The WGSL source of the hemisphere pipeline.
pub const SHADER: &str = include_str!("../../shaders/hemisphere.wgsl");

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct ShotUniform {
    res: [u32; 4],
    tiles: [u32; 4],
    own: [u32; 4],
    depth: [f32; 4],
    /// 1 / each of `tiles` (the shader multiplies rather than divides).
    per_tile: [f32; 4],
}

/// One piece as the tessellated projection's fragment shader reads it (see
/// the shader's `Piece`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PieceGpu {
    plane: [f32; 4],
    item: [u32; 4],
    origin: [f32; 4],
    axis: [f32; 4],
    bilinear: [f32; 4],
    grid: [u32; 4],
}

/// Time spent in the phases of one rasterisation.
#[derive(Clone, Copy, Debug, Default)]
pub struct RasterStats {
    /// Finding the cell rectangles on the CPU.
    pub bounds: Duration,
    /// Rectangles drawn (seam copies included; one cut into pieces at a
    /// rank's tiles counts once), or triangles with the tessellated projection.
    pub rects: u32,
    /// Proxies whose cell rectangle was computed: over several ranks, only
    /// those of polygons that may show in the rank's tiles.
    pub bounded: u32,
    /// Of `rects`, those left undrawn as hidden behind nearer geometry
    /// ([`HemisphereRasterizer::set_cull_occluded`]).
    pub occluded: u32,
    /// Proxies the cull left out before bounding them (not in `rects`):
    /// one process on one core walks the polygons nearest first and skips
    /// what nearer ones already hide.
    pub skipped: u32,
    /// Uploading, drawing and waiting for the GPU.
    pub rasterise: Duration,
    /// Mapping the item buffer and copying it out.
    pub readback: Duration,
}

/// Pipelines, buffers and scene geometry for hemisphere rendering, created once.
pub struct HemisphereRasterizer {
    res: Resolution,
    far: f32,
    /// Every polygon's rasterisation proxies.
    proxies: Proxies,
    /// The mesh's closed solids, and per shot whether the shooter is outside
    /// each (then its back faces are not drawn: see `Mesh::solids`).
    solids: Vec<crate::mesh::Solid>,
    outside: Vec<bool>,
    cull_solids: bool,
    /// Rectangles of the current shot, CPU side (reused).
    instances: Vec<Instance>,
    /// Who draws on the device, and its objects (the tessellated
    /// projection's too, when chosen: see
    /// [`HemisphereRasterizer::use_tessellation`]).
    device: DeviceCells,
    /// Whether to count coverage this shot.
    count_coverage: bool,
    /// Whether the CPU drawing packs each element's visible cells with
    /// its coverage (see [`HemisphereRasterizer::set_pack_visible`]), and
    /// whether the last shot did.
    pack_visible: bool,
    packed: bool,
    /// Whether to leave out polygons hidden behind nearer ones.
    cull_occluded: bool,
    /// The occlusion cull's map, reused from shot to shot.
    occlusion: crate::occlusion::OcclusionMap,
    /// Per shooter polygon, its shots to draw without the cull before
    /// trying it again (it did not pay on the polygon's last shot that
    /// tried it). Per polygon, because a batch hands one rank rows of many
    /// polygons in turn: a light that sees nothing hidden must not turn
    /// the cull off for the next shooter's row.
    cull_waits: std::collections::HashMap<u32, u32>,
    /// This rank's tiles as the bounds read them, kept while the layout
    /// and the rank's place in it stay the same.
    ownership: Option<Ownership>,
    /// The last shot's elements with a covered cell and their counts, in
    /// element order (empty unless counting).
    coverage: Vec<(u32, u64)>,
    elements: usize,
    /// The exact projection drawn on the CPU instead of the device, when
    /// chosen (see [`HemisphereRasterizer::set_software`]).
    software: Option<crate::raster::software::Software>,
}

impl HemisphereRasterizer {
    /// Builds the pipeline and the per-shot buffers for `mesh`. `pieces`
    /// says what is drawn: with N >= 1 every quad polygon is drawn as at most
    /// N x N pieces (never more than its element grid) and the fragment
    /// shader finds the element from the hit point's (u, v), so a shot costs
    /// what the visible geometry costs; with 0 every element is drawn on its
    /// own. Triangles are always drawn per element. Results are the same
    /// either way. `extent` bounds every distance in the scene.
    pub fn new(
        device: &wgpu::Device,
        mesh: &Mesh,
        res: Resolution,
        pieces: u32,
        extent: f32,
    ) -> Result<Self, GpuError> {
        let shapes = Arc::new(ProxyShapes::build(mesh, pieces));
        Self::sharing(device, mesh, res, shapes, extent)
    }

    /// As [`HemisphereRasterizer::new`], drawing `shapes`, built for `mesh`
    /// by [`ProxyShapes::build`] and perhaps shared with other rasterisers
    /// of the same mesh, which spares building them again.
    pub fn sharing(
        device: &wgpu::Device,
        mesh: &Mesh,
        res: Resolution,
        shapes: Arc<ProxyShapes>,
        extent: f32,
    ) -> Result<Self, GpuError> {
        let proxies = Proxies::sharing(shapes);
        let proxy_count = proxies.corners.len();
        let [instance_bytes, coverage_bytes] =
            device::sizes(&device.limits(), res, proxy_count, mesh.elements.len())?;
        use wgpu::BufferUsages as U;
        // Starts small and grows to the largest shot: a shot draws what it
        // sees (Sponza: about a thousand of its 1.2 M proxies), and a buffer
        // sized for every proxy was 377 MB of memory that wgpu zeroes.
        let instance_buf = buffer(
            device,
            "rectangles",
            instance_bytes.min(INITIAL_INSTANCE_BYTES),
            U::VERTEX | U::COPY_DST,
        );
        let uniform_bytes = std::mem::size_of::<ShotUniform>() as u64;
        let uniform = buffer(device, "shot", uniform_bytes, U::UNIFORM | U::COPY_DST);
        let coverage_usage = U::STORAGE | U::COPY_SRC | U::COPY_DST;
        let coverage_buf = buffer(device, "coverage", coverage_bytes, coverage_usage);
        let readback_usage = U::MAP_READ | U::COPY_DST;
        let coverage_read = buffer(device, "coverage readback", coverage_bytes, readback_usage);
        let trig = direction_buffer(device, res)?;
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("hemisphere.wgsl"),
            source: wgpu::ShaderSource::Wgsl(SHADER.into()),
        });
        let pipeline = rect_pipeline(device, &module);
        let group = item_bind_group(device, &pipeline, &[&uniform, &coverage_buf, &trig]);
        let target = RenderTarget::new(
            device,
            res.cols,
            res.rows,
            wgpu::TextureFormat::R32Uint,
            4,
            "item buffer",
        );
        Ok(Self {
            res,
            far: extent.max(1e-6) * 2.0,
            instances: Vec::with_capacity(proxy_count),
            proxies,
            solids: mesh.solids.clone(),
            outside: Vec::new(),
            cull_solids: true,
            device: DeviceCells {
                res,
                elements: mesh.elements.len(),
                instance_buf,
                uniform,
                pipeline,
                group,
                target,
                coverage_buf,
                coverage_read,
                trig,
                module,
                tess: None,
            },
            count_coverage: false,
            pack_visible: false,
            packed: false,
            cull_occluded: true,
            occlusion: crate::occlusion::OcclusionMap::new(res),
            cull_waits: std::collections::HashMap::new(),
            ownership: None,
            coverage: Vec::new(),
            elements: mesh.elements.len(),
            software: None,
        })
    }

    /// Whether shots skip the back faces of closed solids they are outside
    /// of (on by default; the item buffer is the same either way, cell for
    /// cell, but for rays grazing a silhouette edge).
    pub fn set_cull_solids(&mut self, on: bool) {
        self.cull_solids = on;
    }

    /// Whether to leave undrawn the polygons that nearer pieces certainly
    /// hide in every cell they could cover (`crate::occlusion`; on by
    /// default), in every rank's tiles: a polygon hidden in one rank's
    /// tiles may show in another's (and its elements' covered cells would
    /// then be short), so the ranks agree through the `agree` that
    /// [`HemisphereRasterizer::render`] is given. A culled polygon's
    /// elements are all hidden, so no form factor changes.
    pub fn set_cull_occluded(&mut self, on: bool) {
        self.cull_occluded = on;
    }

    /// The most threads the next shots' bounds use (by default every
    /// core, up to 8). One, while another thread does other work of the
    /// shot: on one core the bounds walk the polygons nearest first and
    /// skip what they already hide (the same rectangles either way).
    pub fn set_bounds_threads(&mut self, threads: usize) {
        self.proxies.max_threads = threads;
    }

    /// Whether the exact projection's cells are drawn on the CPU
    /// (`raster::software`) rather than by the device: where the device is
    /// itself a CPU rasteriser (lavapipe), the same test costs a fraction
    /// there. The tessellated projection is always the device's, and so
    /// is a mesh with an element grid of 2^20 or more along an edge.
    pub fn set_software(&mut self, on: bool) {
        // (No real mesh has a grid too long for the CPU's arithmetic.)
        let fits = self
            .proxies
            .quads
            .iter()
            .all(|q| crate::raster::software::fits(q.grid));
        self.software =
            (on && fits).then(|| crate::raster::software::Software::new(self.res, self.elements));
    }

    /// Whether shots draw on the CPU ([`HemisphereRasterizer::set_software`]).
    pub fn software(&self) -> bool {
        self.software.is_some()
    }

    /// Which solids `shooter` is outside of (their back faces need no drawing).
    fn find_outside(&mut self, shooter: &ShooterFrame) {
        let cull = self.cull_solids;
        self.outside.clear();
        self.outside
            .extend(self.solids.iter().map(|s| cull && !s.holds(shooter.centre)));
    }

    /// Whether each shot also counts, per element, every cell whose ray hits
    /// the element whether or not something nearer hides it (see [`HemisphereRasterizer::coverage_pairs`]).
    pub fn set_count_coverage(&mut self, on: bool) {
        self.count_coverage = on;
        if !on {
            self.coverage.clear();
        }
    }

    /// Whether a shot drawn on the CPU over one rank's whole hemisphere, with
    /// coverage counted, also counts each element's visible cells into its
    /// coverage pair (visible << 32 | covered, `formfactor::unpack`'s
    /// packing: what the hybrid method sums from the items), so the items
    /// need not be summed again.
    pub fn set_pack_visible(&mut self, on: bool) {
        self.pack_visible = on;
    }

    /// Whether the last shot's coverage pairs hold packed visible counts
    /// (see [`HemisphereRasterizer::set_pack_visible`]).
    pub fn coverage_packs_visible(&self) -> bool {
        self.packed
    }

    /// The last shot's unoccluded cell counts (this rank's cells only), as
    /// (element, count) for every element with some; none unless
    /// [`HemisphereRasterizer::set_count_coverage`] is on.
    pub fn coverage_pairs(&self) -> impl Iterator<Item = (u32, u64)> + '_ {
        self.coverage.iter().copied()
    }

    /// The hemisphere resolution.
    pub fn resolution(&self) -> Resolution {
        self.res
    }

    /// Renders the cells of the tiles that rank `own` of `layout` owns, as seen
    /// from `shooter`, into `items` (row-major, R_phi x R_theta). Cells other
    /// ranks own are [`EMPTY`]. With `peers` (one rank drawing the whole
    /// hemisphere, or every rank of a run, each its tiles): its `agree`
    /// leaves polygons hidden in every rank's cells undrawn
    /// ([`HemisphereRasterizer::set_cull_occluded`]); every rank must then
    /// pass one, and each calls it once a shot or never. Its `scatter`
    /// (ranks of a run, tiles cut out) deals the polygons' bounds between
    /// the ranks, called once a shot by every rank.
    // The device and queue apart (wgpu's examples' style, so tests inject
    // them), the tiles, the output and the ranks' agreement: all needed.
    #[allow(clippy::too_many_arguments)]
    pub fn render(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        shooter: &ShooterFrame,
        layout: &TileLayout,
        own: (u32, u32),
        items: &mut Vec<u32>,
        peers: Option<Peers<'_>>,
    ) -> Result<RasterStats, GpuError> {
        let start = Instant::now();
        self.packed = false;
        let (collected, lattice) = self.find_rects(shooter, layout, own, peers);
        let bounds = start.elapsed();
        let shot = CellShot {
            instances: &self.instances,
            far: self.far,
            layout,
            own,
            lattice,
            coverage: self.count_coverage,
            pack_visible: self.pack_visible,
        };
        let tessellated = self.device.tess.is_some();
        let drawn = match self.software.as_mut().filter(|_| !tessellated) {
            Some(cpu) => match cpu.draw((), &shot, items, &mut self.coverage) {
                Ok(drawn) => drawn,
                Err(never) => match never {},
            },
            None => self
                .device
                .draw((device, queue), &shot, items, &mut self.coverage)?,
        };
        self.packed = drawn.packed;
        let (rasterise, readback) = (drawn.rasterise, drawn.readback);
        Ok(RasterStats {
            bounds,
            rects: match &self.device.tess {
                Some(t) => (t.vertices.len() / 3) as u32,
                None => collected.rects as u32,
            },
            bounded: collected.bounded as u32,
            occluded: collected.culled.map_or(0, |c| c.rects as u32),
            skipped: collected.skipped as u32,
            rasterise,
            readback,
        })
    }

    /// A shot's first half, on the CPU: this rank's tiles as the bounds
    /// read them, the shooter's side of each closed solid, and the
    /// rectangles (or the tessellated projection's triangles) to draw,
    /// with the occlusion cull and the ranks' deal where they apply.
    /// Returns what was collected and whether the rank's cells are drawn
    /// packed (1 x 1 tiles over several ranks).
    fn find_rects(
        &mut self,
        shooter: &ShooterFrame,
        layout: &TileLayout,
        own: (u32, u32),
        peers: Option<Peers<'_>>,
    ) -> (crate::raster::proxies::Collected, bool) {
        // With 1 x 1 tiles over several ranks, draw only this rank's cells,
        // packed (see the shader); otherwise draw all and discard others' cells.
        // The tessellated projection always draws the full image: packing
        // would move its vertices relative to the rasteriser's sub-pixel
        // grid, and rank counts would no longer agree bit for bit.
        let lattice = layout.tile_w == 1
            && layout.tile_h == 1
            && layout.ranks() > 1
            && self.device.tess.is_none();
        // Over several ranks, skip rectangles that hold none of this rank's cells.
        if layout.ranks() > 1 {
            let place = TilePlace {
                tile: [layout.tile_w, layout.tile_h],
                grid: [layout.px, layout.py],
                own: [own.0, own.1],
                cells: [self.res.cols, self.res.rows],
                clip: !lattice,
            };
            if self.ownership.as_ref().is_none_or(|o| o.place != place) {
                self.ownership = Some(Ownership::new(place));
            }
        } else {
            self.ownership = None;
        }
        self.find_outside(shooter);
        // Every rank decides alike (the wait follows the share summed over
        // ranks), so all take part in the agreement or none.
        let (agree, scatter) = match peers {
            Some(p) => (Some(p.agree), p.scatter),
            None => (None, None),
        };
        let waiting = match self.cull_waits.get_mut(&shooter.polygon) {
            Some(wait) if *wait > 1 => {
                *wait -= 1;
                true
            }
            Some(_) => {
                self.cull_waits.remove(&shooter.polygon);
                true
            }
            None => false,
        };
        let cull = self.cull_occluded && !waiting && agree.is_some();
        let mut collected = crate::raster::proxies::Collected::default();
        if self.device.tess.is_some() {
            self.collect_triangles(shooter);
        } else {
            collected = self.proxies.collect_rects(
                shooter,
                &self.outside,
                self.res,
                self.far,
                self.ownership.as_ref(),
                agree
                    .filter(|_| cull)
                    .map(|agree| (&mut self.occlusion, agree)),
                scatter,
                &mut self.instances,
            );
            // Where the cull left little out, the polygon's next shots skip
            // it: its cost is that of drawing every rectangle's cells on the
            // CPU. The bits are the same.
            if collected.culled.is_some_and(|c| c.share < CULL_PAYS) {
                self.cull_waits.insert(shooter.polygon, CULL_RETRY);
            }
        }
        (collected, lattice)
    }
}

/// What a rank asks of the others while it finds a shot's rectangles
/// (see [`HemisphereRasterizer::render`]).
pub struct Peers<'a> {
    /// The occlusion cull's agreement.
    pub agree: Agree<'a>,
    /// The rectangles' deal between the ranks of a run (`None` for one
    /// process).
    pub scatter: Option<Scatter<'a>>,
}

/// Coverage counts tested for zero at once (see `read_coverage`).
const COVERAGE_BLOCK: usize = 64;

/// The occlusion cull pays where it leaves out at least this share of the
/// cells the shot's rectangles hold (on lavapipe a fragment costs several
/// times what the cull's test of a cell costs on the CPU).
const CULL_PAYS: f64 = 0.1;

/// Shots of a polygon drawn without the cull after one where it did not pay.
const CULL_RETRY: u32 = 16;

/// The most rectangles one draw call draws (see [`HemisphereRasterizer::submit`]).
const DRAW_INSTANCES: u32 = 1 << 12;

/// The rectangle buffer's first size (it grows to the largest shot).
const INITIAL_INSTANCE_BYTES: u64 = 1 << 20;
