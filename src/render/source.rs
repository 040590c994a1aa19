//! The GPU form-factor source: for each shot, a row from the cache or a
//! hemisphere drawn (at the tier the shooter's power asks for) by every
//! rank, exchanged, and turned into a row of form factors (hemisphere sums,
//! or hybrid rows, split where visibility varies across the shooter).

use super::cache::{RowCache, RowKey};
use super::exchange::Exchanger;
use super::options::{RenderError, RenderOptions};
use super::tiers::{layout_for, TierCells, TierChoice};
use crate::formfactor::{self, Row};
use crate::gpu::{Gpu, GpuError, HemisphereRasterizer};
use crate::hemisphere::{FormFactorAccumulator, Resolution, TileLayout, EMPTY, FIXED_ONE};
use crate::lit_mesh::LitMesh;
use crate::mesh::{Mesh, ShooterFrame};
use crate::parallel::{self, Collectives, Single};
use crate::raster::{ProxyShapes, Scatter};
use crate::settings::{FormFactorMethod, Projection, Rasteriser};
use crate::solver::{FormFactorSource, ShotRegion, Transfer};
use std::sync::Arc;
use std::time::{Duration, Instant};

mod drawn;
pub(in crate::render) use drawn::Parts;
mod far;
mod rows;
mod split;
mod transport;

use far::FarPatch;
pub use far::FAR_CELLS;
use split::{First, Split};
pub use split::{GroupPart, Started};

/// Time one rank spent per phase, summed over shots.
#[derive(Clone, Copy, Debug, Default)]
pub struct PhaseTimes {
    /// Finding cell rectangles (CPU).
    pub bounds: Duration,
    /// Drawing and waiting for the GPU.
    pub rasterise: Duration,
    /// Reading the item buffer back.
    pub read_back: Duration,
    /// The form-factor exchange between ranks.
    pub exchange: Duration,
    /// Summing delta form factors.
    pub sum: Duration,
    /// Of `sum`: the far receivers' shadow rays (see
    /// `GpuFormFactors::add_far_receivers`).
    pub far: Duration,
    /// The far receivers' centre rays cast on another thread while the
    /// hemisphere was drawn (`GpuFormFactors::far_ahead`; not in `sum`).
    pub far_ahead: Duration,
    /// Rectangles in view (bounded, before the occlusion cull).
    pub rects: u64,
    /// Of those, rectangles the occlusion cull left undrawn.
    pub occluded: u64,
    /// Proxies the occlusion cull left out before bounding them.
    pub skipped: u64,
    /// What the ranks' agreements on the cull moved (not the exchange's).
    pub cull_traffic: parallel::Traffic,
    /// What the ranks' deal of the rectangles moved (not the exchange's).
    pub rect_traffic: parallel::Traffic,
    /// Proxies whose cell rectangle this rank computed (the bounds pass's
    /// work: over several ranks, only polygons that may show in its tiles).
    pub bounded: u64,
    /// Hemisphere cells this rank drew (its tiles' cells, summed over the
    /// shots it drew): work the ranks divide.
    pub cells: u64,
    /// Receiving elements whose form factors this rank summed (entries of
    /// the rows it computed, summed over shots).
    pub receivers: u64,
    /// Shots answered from the form-factor row cache (no rasterisation).
    pub cached: u64,
    /// Shots split into one hemisphere per group of shooter elements.
    pub split: u64,
    /// Shots drawn at the coarse resolution (weak shooters).
    pub coarse: u64,
    /// Shots along the ambient term's transport (`--transport-below`).
    pub transported: u64,
    /// The row cache a rank may hold, bytes (what its memory budget left).
    pub cache_budget: u64,
    /// Shots whose row was drawn ahead, beside an earlier shot
    /// (`render::ahead`).
    pub drawn_ahead: u64,
}

impl PhaseTimes {
    /// Time drawing (bounds, rasterising, reading back).
    fn drawing(&self) -> Duration {
        self.bounds + self.rasterise + self.read_back
    }
}

/// One resolution tier: its rasteriser and its cells.
struct Tier {
    raster: HemisphereRasterizer,
    cells: TierCells,
    /// How its whole hemispheres find their far receivers.
    far_way: far::FarWay,
}

impl Tier {
    /// Uploads the mesh and builds the pipelines for resolution `res`.
    fn new(
        (gpu, mesh): (&Gpu, &Mesh),
        opts: &RenderOptions,
        res: Resolution,
        ranks: usize,
        extent: f32,
        shapes: &Arc<ProxyShapes>,
    ) -> Result<Self, RenderError> {
        let layout = layout_for(opts, res, ranks)?;
        let shapes = Arc::clone(shapes);
        let mut raster = HemisphereRasterizer::sharing(&gpu.device, mesh, res, shapes, extent)?;
        if opts.projection == Projection::Tessellated {
            raster.use_tessellation(&gpu.device, opts.tessellation_tolerance)?;
        }
        raster.set_count_coverage(opts.form_factor == FormFactorMethod::Hybrid);
        // The hybrid method's weights count a visible cell as VISIBLE_ONE:
        // the CPU drawing can count them itself.
        raster.set_pack_visible(opts.form_factor == FormFactorMethod::Hybrid);
        raster.set_cull_occluded(opts.occlusion_cull);
        raster.set_software(opts.rasteriser_for(gpu.is_cpu()) == Rasteriser::Cpu);
        Ok(Self {
            raster,
            cells: TierCells::new(res, layout, ranks, opts.form_factor),
            far_way: far::FarWay::default(),
        })
    }
}

/// What sibling sources of one mesh and one set of options share, read-only:
/// built once, not once a tier and once a source (Sponza's proxies took
/// about a second each, which the rows drawn ahead paid beside the first
/// shots).
#[derive(Clone)]
pub(in crate::render) struct Shared {
    /// Every tier's rasterisation proxies.
    shapes: Arc<ProxyShapes>,
    /// The receivers as hybrid rows read them.
    receivers: Arc<formfactor::ReceiverTable>,
    /// Per element, the leaf of the occluders' hierarchy holding its
    /// polygon (`u32::MAX`: none), for the far receivers' guesses (see
    /// `far::Guide`).
    guide_leaves: Arc<Vec<u32>>,
}

/// A cached row's cost against a fresh fine one (a rank combines it with
/// the shot's radiosities: measured in microseconds against milliseconds).
const CACHED_ROW_COST: f64 = 0.02;

/// Form factors by rasterising the hemisphere on the GPU, tile by tile, and
/// exchanging them between ranks as DESIGN.md section 3 describes. Returns
/// the form factors of this rank's elements only.
pub struct GpuFormFactors<'a> {
    gpu: &'a Gpu,
    mesh: &'a LitMesh,
    comm: &'a dyn Collectives,
    /// The hemisphere at the shot resolution, and at the coarse one for weak
    /// shooters (see [`RenderOptions::coarse_below`]).
    tiers: Vec<Tier>,
    choice: TierChoice,
    /// The rank and rank count whose elements a transport row reaches:
    /// the communicator's, or, for a batched solve's source of one process,
    /// the run's (a weak shooter's transport row is cheap and split by
    /// owner, not drawn whole).
    transport_ranks: (usize, usize),
    /// The tier the last hemisphere was drawn in.
    last_tier: usize,
    method: FormFactorMethod,
    exchanger: Exchanger<'a>,
    acc: FormFactorAccumulator,
    items: Vec<u32>,
    pairs: Vec<(u32, u64)>,
    /// What the last hemisphere's cells (this rank's) showed (see
    /// [`TierCells::view_shares`]).
    view: [u64; 3],
    /// The last shot's back-face share (see [`Row::blocked`]).
    last_blocked: f64,
    /// Time spent so far.
    pub timings: PhaseTimes,
    /// This rank's busy time (everything but waiting in collectives) per shot.
    pub busy: Vec<f64>,
    /// The same spans in process CPU seconds, less the CPU inside collective
    /// calls: the rank's own work, which more ranks than cores do not
    /// inflate as they inflate wall times.
    pub busy_cpu: Vec<f64>,
    /// Per patch, from its first uncached hybrid shot: this rank's receivers'
    /// penumbra and total shares (see `refine::PatchStats`).
    pub penumbra: Vec<[u64; 2]>,
    /// Form-factor rows of patches that have shot, for when they shoot again.
    /// Keyed by tier too: a weak shot of a patch that first shot strong
    /// draws (once) at the coarse tier, so that the cache, and a resumed
    /// solve's empty one, change no number.
    cache: RowCache,
    /// Whether shots split where visibility varies across the shooter.
    split: bool,
    /// Per patch, whether the last hemisphere's cells saw it (a visible cell).
    seen: Vec<bool>,
    /// The receivers as hybrid rows and the marking of patches seen read
    /// them (compact: see [`formfactor::ReceiverTable`]).
    receivers: Arc<formfactor::ReceiverTable>,
    /// Per element, its polygon's leaf of the occluders ([`Shared`]).
    guide_leaves: Arc<Vec<u32>>,
    /// Every tier's rasterisation proxies (shared with a sibling source).
    shapes: Arc<ProxyShapes>,
    /// What the far receivers' scan reads of each of this rank's patches,
    /// contiguous (see [`FarPatch`]).
    far_patches: Vec<FarPatch>,
    /// Per tile this rank drew, the item buffer of the last whole (not
    /// reach-limited) hemisphere (see [`GpuFormFactors::view_of`]).
    whole_items: Vec<Vec<u32>>,
    /// A split group's items with the whole hemisphere's beyond its reach.
    composite: Vec<u32>,
    /// Split shots started here whose groups are being drawn (a batched
    /// solve's: see [`GpuFormFactors::start_row`]).
    pending: Vec<split::Pending>,
    /// A transport row's sort keys and its transfers in element order
    /// (kept between shots).
    sort_keys: Vec<u64>,
    sorted: Vec<Transfer>,
    /// The largest distance from a patch's centre to its corners.
    max_patch_radius: f32,
    /// Whether this run's ranks deal the polygons' bounds (the same on every rank).
    deal: bool,
    /// The scene's extent the rasterisers were built for (a sibling source
    /// is built alike: see `render::ahead`).
    extent: f32,
}

impl<'a> GpuFormFactors<'a> {
    /// The source of a solve over `comm`'s ranks: a batched one
    /// (`--batch`) draws whole hemispheres on every rank, so its source is
    /// one process's (`one`), its transport rows still this rank's
    /// elements'; otherwise the ranks split each hemisphere over `comm`.
    pub fn for_solve(
        gpu: &'a Gpu,
        mesh: &'a LitMesh,
        opts: &RenderOptions,
        (comm, one): (&'a dyn Collectives, &'a Single),
        extent: f32,
    ) -> Result<Self, RenderError> {
        let source_comm: &dyn Collectives = if opts.batch > 1 { one } else { comm };
        let mut source = Self::new(gpu, mesh, opts, source_comm, extent)?;
        source.set_transport_ranks(comm.rank(), comm.size());
        Ok(source)
    }

    /// Uploads the mesh and builds the pipelines. With one process and a
    /// multi-rank `layout`, every rank's tiles are drawn here in turn.
    pub fn new(
        gpu: &'a Gpu,
        mesh: &'a LitMesh,
        opts: &RenderOptions,
        comm: &'a dyn Collectives,
        extent: f32,
    ) -> Result<Self, RenderError> {
        let shared = Shared {
            shapes: Arc::new(ProxyShapes::build(mesh, opts.raster_pieces)),
            receivers: Arc::new(formfactor::ReceiverTable::new(mesh)),
            guide_leaves: Arc::new(far::guide_leaves(mesh)),
        };
        Self::sharing((gpu, mesh), opts, comm, extent, shared)
    }

    /// As [`GpuFormFactors::new`], with what another source of the same
    /// mesh and options shares (see [`Shared`]).
    fn sharing(
        (gpu, mesh): (&'a Gpu, &'a LitMesh),
        opts: &RenderOptions,
        comm: &'a dyn Collectives,
        extent: f32,
        shared: Shared,
    ) -> Result<Self, RenderError> {
        let n = comm.size();
        let tiers = TierChoice::resolutions(opts)
            .into_iter()
            .map(|res| Tier::new((gpu, mesh), opts, res, n, extent, &shared.shapes))
            .collect::<Result<Vec<_>, _>>()?;
        let patches = mesh.elements.iter().map(|e| e.patch);
        // Every rank has the same options, so all or none meet in the collective.
        let per_rank_cache = if opts.cache_rows {
            cache_budget(opts, comm)
        } else {
            0
        };
        Ok(Self {
            gpu,
            mesh,
            comm,
            tiers,
            // Against all the light, the lights' and sky's too: measured
            // against the surfaces' emission alone, a scene lit only by a
            // sun had no weak shot and never drew the coarse tier.
            choice: TierChoice::new(opts, mesh.source_power(), mesh.patches.len()),
            transport_ranks: (comm.rank(), comm.size()),
            last_tier: 0,
            method: opts.form_factor,
            exchanger: Exchanger::new(
                comm,
                (opts.exchange, opts.form_factor),
                parallel::Owners::new(mesh.patches.len(), comm.size()),
                patches,
            ),
            acc: FormFactorAccumulator::new(mesh.elements.len()),
            items: Vec::new(),
            pairs: Vec::new(),
            view: [0; 3],
            last_blocked: 0.0,
            timings: PhaseTimes {
                cache_budget: per_rank_cache,
                ..PhaseTimes::default()
            },
            busy: Vec::new(),
            busy_cpu: Vec::new(),
            penumbra: vec![[0, 0]; mesh.patches.len()],
            cache: RowCache::for_ranks(opts.cache_rows, per_rank_cache, n),
            split: opts.split_shots,
            seen: vec![false; mesh.patches.len()],
            receivers: shared.receivers,
            guide_leaves: shared.guide_leaves,
            shapes: shared.shapes,
            far_patches: FarPatch::owned(mesh, comm.rank(), n),
            max_patch_radius: mesh
                .patches
                .iter()
                .flat_map(|p| p.corners.iter().map(|c| c.distance(p.centre)))
                .fold(0.0, f32::max),
            whole_items: Vec::new(),
            composite: Vec::new(),
            pending: Vec::new(),
            sort_keys: Vec::new(),
            sorted: Vec::new(),
            deal: opts.deal_bounds.deals(n, mesh.polygons.len()),
            extent,
        })
    }

    /// Drops the row cache (once the solve is over: what comes next, the
    /// gather and the image, needs the memory more).
    pub fn release_cache(&mut self) {
        self.cache = RowCache::new(0);
    }

    /// Bytes of the row computed by the last shot that the cache has not
    /// decided on yet (this rank's share).
    pub fn pending_bytes(&self) -> u64 {
        self.cache.pending_bytes()
    }

    /// Keeps the pending row if the cache has room for `all_ranks_bytes`
    /// (the pending bytes summed over ranks, the same number on every rank).
    pub fn settle_cache(&mut self, all_ranks_bytes: u64) {
        self.cache.settle(all_ranks_bytes);
    }

    /// The tile layout in use.
    pub fn layout(&self) -> TileLayout {
        self.tiers[0].cells.layout
    }

    /// The share of the last shot that met the backs of one-sided
    /// surfaces (the same on every rank; see [`Row::blocked`]).
    pub fn last_blocked(&self) -> f64 {
        self.last_blocked
    }

    /// The item buffer of the last hemisphere this rank drew, and its resolution.
    pub fn last_items(&self) -> (&[u32], Resolution) {
        (&self.items, self.tiers[self.last_tier].cells.resolution)
    }

    /// Draws the hemisphere of `shooter` at `centre` (every rank its tiles)
    /// in tier `tier`, exchanges, and leaves this rank's per-element sums in
    /// `self.pairs`. Returns the time spent in the exchange.
    fn hemisphere(
        &mut self,
        shooter: u32,
        centre: glam::Vec3,
        tier: usize,
        reach: f32,
    ) -> Result<Duration, RenderError> {
        // Near receivers are drawn even when hidden: their hidden cells
        // decide whether the shot splits (`formfactor::needs_split`).
        let (_, near) = formfactor::near_receivers(self.mesh, shooter);
        let sp = self.mesh.patches[shooter as usize].centre;
        let keep = (near as f32 + centre.distance(sp)) * (1.0 + 1e-4);
        let frame = self
            .mesh
            .shooter_frame_at(shooter, centre)
            .within(reach)
            .keeping_near(keep);
        if reach.is_infinite() {
            // Read by scripts/bench-packets.sh, which casts these
            // hemispheres' rays with Embree's ray packets.
            log::trace!(
                target: "radiosity::hemispheres",
                "hemisphere {:?} {:?} {:?} {:?}",
                frame.centre.to_array(),
                frame.tangent.to_array(),
                frame.bitangent.to_array(),
                frame.normal.to_array()
            );
        }
        self.last_tier = tier;
        let layout = self.tiers[tier].cells.layout;
        let mut exchange = Duration::ZERO;
        self.view = [0; 3];
        let cut = reach.is_finite();
        let mut packed = false;
        if self.comm.size() == 1 {
            // One process, perhaps standing in for a rank grid: draw every
            // rank's tiles in turn.
            for (t, own) in (0..layout.py)
                .flat_map(|ry| (0..layout.px).map(move |rx| (rx, ry)))
                .enumerate()
            {
                self.draw(&frame, own)?;
                let v = self.view_of(tier, t, own, cut);
                self.view = [0, 1, 2].map(|i| self.view[i] + v[i]);
                let Tier { raster, cells, .. } = &self.tiers[tier];
                if raster.coverage_packs_visible() {
                    // The drawing counted every element's visible and
                    // covered cells (one tile: the whole hemisphere).
                    packed = true;
                    self.pairs.clear();
                    self.pairs.extend(raster.coverage_pairs());
                } else {
                    Exchanger::add_own(&mut self.acc, cells, &self.items, raster.coverage_pairs());
                }
            }
        } else {
            let own = self.tiers[tier].cells.grid_position(self.comm.rank());
            self.draw(&frame, own)?;
            self.view = self.view_of(tier, 0, own, cut);
            let Tier { raster, cells, .. } = &mut self.tiers[tier];
            exchange =
                self.exchanger
                    .exchange(&mut self.acc, cells, &self.items, raster.coverage_pairs());
        }
        if self.acc.take_overflow() {
            return Err(RenderError::Overflow(shooter));
        }
        if !packed {
            self.acc.drain_fixed(&mut self.pairs);
        }
        Ok(exchange)
    }

    /// What the hemisphere just drawn in this rank's tile `t` (drawing order)
    /// at grid position `own` shows, as [`TierCells::view_shares`]. A whole
    /// hemisphere's items are kept; one `cut` short at a reach (a split
    /// group's) takes, where it shows nothing, what the kept one showed:
    /// beyond its reach the group sees what the shot's centre saw.
    fn view_of(&mut self, tier: usize, t: usize, own: (u32, u32), cut: bool) -> [u64; 3] {
        let cells = &self.tiers[tier].cells;
        if !cut {
            if self.whole_items.len() <= t {
                self.whole_items.resize_with(t + 1, Vec::new);
            }
            self.whole_items[t].clone_from(&self.items);
            return cells.view_shares(&self.items, own);
        }
        let Some(whole) = self.whole_items.get(t) else {
            return cells.view_shares(&self.items, own);
        };
        self.composite.clear();
        self.composite.extend(
            self.items
                .iter()
                .zip(whole)
                .map(|(&g, &w)| if g == EMPTY { w } else { g }),
        );
        cells.view_shares(&self.composite, own)
    }

    /// Draws this rank's tiles `own` of the last tier's hemisphere.
    fn draw(&mut self, frame: &ShooterFrame, own: (u32, u32)) -> Result<(), GpuError> {
        let tier = &mut self.tiers[self.last_tier];
        // The occlusion cull's agreement: one process drawing the whole
        // hemisphere needs nobody; ranks of a run gather every rank's
        // verdicts (that traffic kept apart from the exchange's). One
        // process standing in for a rank grid draws no culls.
        let comm = self.comm;
        let whole = comm.size() == 1 && tier.cells.layout.ranks() == 1;
        let mut cull_traffic = parallel::Traffic::default();
        let mut agree = |message: &[u32]| -> Vec<Vec<u32>> {
            if comm.size() == 1 {
                return vec![message.to_vec()];
            }
            let before = comm.traffic();
            let all = comm.all_gather_u32(message, None);
            cull_traffic = cull_traffic.plus(comm.traffic().since(before));
            all
        };
        // Ranks of a run deal the polygons' bounds and send each other the
        // pieces in their tiles (that traffic, too, kept apart).
        let mut rect_traffic = parallel::Traffic::default();
        let mut scatter = |outgoing: &[Vec<u32>]| -> Vec<Vec<u32>> {
            let before = comm.traffic();
            let all = comm.all_to_all_u32(outgoing);
            rect_traffic = rect_traffic.plus(comm.traffic().since(before));
            all
        };
        let peers = (whole || comm.size() > 1).then(|| crate::gpu::Peers {
            agree: &mut agree,
            scatter: self.deal.then_some(&mut scatter as Scatter<'_>),
        });
        let stats = tier.raster.render(
            &self.gpu.device,
            &self.gpu.queue,
            frame,
            &tier.cells.layout,
            own,
            &mut self.items,
            peers,
        )?;
        self.timings.cull_traffic = self.timings.cull_traffic.plus(cull_traffic);
        self.timings.rect_traffic = self.timings.rect_traffic.plus(rect_traffic);
        self.timings.bounds += stats.bounds;
        self.timings.rects += stats.rects as u64;
        self.timings.occluded += stats.occluded as u64;
        self.timings.skipped += stats.skipped as u64;
        self.timings.bounded += stats.bounded as u64;
        self.timings.cells += tier.cells.cells_at(own) as u64;
        self.timings.rasterise += stats.rasterise;
        self.timings.read_back += stats.readback;
        Ok(())
    }
}

/// The row cache each rank may hold: the least that any rank's memory
/// budget leaves (see [`crate::render::cache::cache_budget`]), so that every
/// rank keeps or drops a row alike.
fn cache_budget(opts: &RenderOptions, comm: &dyn Collectives) -> u64 {
    // Ranks that are threads of one process share its resident set: each
    // counts its share against its own budget (`--memory` is a rank's).
    let resident = crate::report::resident_bytes() / parallel::ranks_in_this_process() as u64;
    let own = crate::render::cache::cache_budget(opts.memory_budget, resident);
    let least = if comm.size() == 1 {
        own
    } else {
        // Exact in f64: a byte count below 2^53.
        comm.all_gather_f64(&[own as f64])
            .into_iter()
            .fold(own as f64, f64::min) as u64
    };
    if comm.rank() == 0 {
        log::debug!(
            "row cache: {:.0} MB a rank ({:.0} MB resident of a {:.1} GB budget)",
            least as f64 / 1e6,
            resident as f64 / 1e6,
            opts.memory_budget as f64 / 1e9
        );
    }
    least
}

/// The share of the shot `region` (of patch `shooter`, through `row`) that
/// meets back faces: each shooter element's light weighted by what it
/// shoots (by area when the patch shoots uniformly).
fn back_share(mesh: &Mesh, shooter: u32, row: &Row, region: &ShotRegion) -> f64 {
    let patch = &mesh.patches[shooter as usize];
    let m = row.blocked.len();
    if m <= 1 {
        return row.blocked.first().copied().unwrap_or(0.0);
    }
    let first = patch.elements.start as usize;
    let (mut back, mut all) = (0.0, 0.0);
    for (k, b) in row.blocked.iter().enumerate() {
        let s = region.elements.get(k).unwrap_or(&region.shoot);
        let w = (s[0] + s[1] + s[2]) * mesh.elements[first + k].area;
        back += b * w;
        all += w;
    }
    if all != 0.0 {
        back / all
    } else {
        0.0
    }
}

impl GpuFormFactors<'_> {
    /// Has every shooter but the emitters' patches draw at the coarse tier,
    /// if there is one, with one hemisphere a shot (no split): for the
    /// refinement passes, which only measure (which patches cast penumbrae,
    /// which receivers hold their light unevenly), and whose shots the
    /// final solve draws again.
    pub fn measuring(&mut self) {
        self.choice.measuring = true;
    }

    /// Forgets what `shooter`'s last row measured of its penumbra (another
    /// rank drew its row this time, and holds the new measure).
    pub fn forget_penumbra(&mut self, shooter: u32) {
        if let Some(p) = self.penumbra.get_mut(shooter as usize) {
            *p = [0, 0];
        }
    }

    /// Builds transport rows for rank `rank` of `ranks`' elements only
    /// (a batched solve's source of one process: see `ShotLoop::batched`).
    fn set_transport_ranks(&mut self, rank: usize, ranks: usize) {
        self.transport_ranks = (rank, ranks);
    }

    /// What the row of `shooter` shooting `region` would cost this rank,
    /// in hemispheres of the fine tier: nothing much when its row is in
    /// this rank's cache, a coarse tier's share of the cells, else one
    /// (split shots draw more, which no one knows before). A batch gives
    /// each row to the rank it costs least (see `ShotLoop::step`).
    pub fn row_cost(&self, shooter: u32, region: &ShotRegion) -> f64 {
        if self.choice.by_transport(region.power) {
            return 0.0;
        }
        let tier = self.tier_of(shooter, region);
        if self
            .cache
            .get(&RowKey::new(shooter, region.centre, tier))
            .is_some()
        {
            return CACHED_ROW_COST;
        }
        self.group_cost(shooter, region)
    }

    /// Whether a shooter of unshot power `power` shoots along the ambient
    /// term's transport (`--transport-below`).
    pub fn by_transport(&self, power: f64) -> bool {
        self.choice.by_transport(power)
    }
}

/// A drawn row's time: when it began (wall and CPU), the drawing time
/// before it, what it spent in exchanges, and the time spent on other rows
/// meanwhile (not this row's summing).
struct RowClock {
    start: Instant,
    cpu: parallel::CpuSpan,
    before: Duration,
    exchange: Duration,
    aside: Duration,
}

impl RowClock {
    /// A row drawn with nothing else drawn meanwhile.
    fn alone(start: Instant, cpu: parallel::CpuSpan, before: Duration, exchange: Duration) -> Self {
        Self {
            start,
            cpu,
            before,
            exchange,
            aside: Duration::ZERO,
        }
    }
}

impl FormFactorSource for GpuFormFactors<'_> {
    type Error = RenderError;

    fn form_factors(
        &mut self,
        shooter: u32,
        region: &ShotRegion,
        out: &mut Vec<Transfer>,
    ) -> Result<(), RenderError> {
        self.form_factors_by(shooter, region, out, |source, key, centre| {
            let (row, exchange) = source.own_row(key, centre)?;
            Ok((row, exchange, Duration::ZERO))
        })
    }
}

impl GpuFormFactors<'_> {
    /// As [`FormFactorSource::form_factors`], except that a row to draw
    /// comes from `row` (given this source, the row's key and centre; it
    /// returns the row, the time spent in exchanges and the time spent on
    /// other rows meanwhile, left out of this one's summing): `render::ahead`
    /// hands over rows drawn beside the shot. Transport and cached rows,
    /// the cache's offer and the timings are as ever.
    pub(super) fn form_factors_by(
        &mut self,
        shooter: u32,
        region: &ShotRegion,
        out: &mut Vec<Transfer>,
        row: impl FnOnce(
            &mut Self,
            RowKey,
            glam::Vec3,
        ) -> Result<(Row, Duration, Duration), RenderError>,
    ) -> Result<(), RenderError> {
        let start = Instant::now();
        let cpu = parallel::CpuSpan::start(self.comm);
        let Some((key, _)) = self.fresh_key(shooter, region, out, (start, cpu)) else {
            return Ok(());
        };
        let before = self.timings.drawing();
        let (row, exchange, aside) = row(self, key, region.centre)?;
        let clock = RowClock {
            start,
            cpu,
            before,
            exchange,
            aside,
        };
        self.take_row(key, row, region, out, clock);
        Ok(())
    }
}

impl GpuFormFactors<'_> {
    /// A row that needs no drawing (a transport row, a cached one) into
    /// `out`, returning `None`; else the cache key and tier of the row to
    /// draw. `started` is when (and at what CPU time) the row began.
    fn fresh_key(
        &mut self,
        shooter: u32,
        region: &ShotRegion,
        out: &mut Vec<Transfer>,
        (start, cpu): (Instant, parallel::CpuSpan),
    ) -> Option<(RowKey, usize)> {
        if self.choice.by_transport(region.power) {
            self.transport_row(shooter, region, out);
            self.note_quick_row(start, cpu);
            return None;
        }
        let tier = self.tier_of(shooter, region);
        let key = RowKey::new(shooter, region.centre, tier);
        if let Some(row) = self.cache.get(&key) {
            row.combine(region, out);
            self.last_blocked = back_share(self.mesh, shooter, row, region);
            self.timings.cached += 1;
            self.note_quick_row(start, cpu);
            return None;
        }
        if tier > 0 {
            self.timings.coarse += 1;
        }
        Some((key, tier))
    }

    /// A freshly drawn `row` into `out` and offered to the cache, its time
    /// noted (see [`RowClock`]).
    fn take_row(
        &mut self,
        key: RowKey,
        row: Row,
        region: &ShotRegion,
        out: &mut Vec<Transfer>,
        clock: RowClock,
    ) {
        let RowClock {
            start,
            cpu,
            before,
            exchange,
            aside,
        } = clock;
        row.combine(region, out);
        self.last_blocked = back_share(self.mesh, key.patch, &row, region);
        self.cache.offer(key, row);
        if self.comm.size() == 1 {
            // One process: the decision needs nobody else.
            self.cache.settle(self.cache.pending_bytes());
        }
        let total = start.elapsed();
        let drawn = self.timings.drawing() - before;
        self.timings.exchange += exchange;
        self.timings.sum += total.saturating_sub(exchange + drawn + aside);
        self.busy.push((total - exchange).as_secs_f64());
        self.busy_cpu.push(cpu.own(self.comm));
    }
}
