//! One render from start to finish: scene -> mesh -> form factors on the GPU ->
//! progressive refinement -> image and report. Used by the `radiosity` binary,
//! the tests and the viewer; it joins the modules but adds no maths of its own.

use crate::checkpoint::{Checkpoint, Header};
use crate::formfactor::Row;
use crate::gpu::{render_view, Gpu, GpuError, HemisphereRasterizer, Shading, ViewSettings};
use crate::hemisphere::{FormFactorAccumulator, Resolution, TileLayout};
use crate::mesh::{Mesh, MeshSettings};
use crate::parallel::{rank_grid, Collectives, Exchange, Single, Traffic};
use crate::refine::{self, PatchStats};
use crate::report::{
    self, Counts, LoadBalance, Parallel, RankStats, Refinement, Report, Settings, Timings,
    TracePoint,
};
use crate::scene::Scene;
use crate::solver::{
    Candidate, FormFactorSource, NetUnshot, ShotRegion, Solver, StopRule, Transfer, UNSHOT_ONE,
};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How the form factor from a shooter to each element is evaluated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum FormFactorMethod {
    /// Spencer's hemisphere alone: the sum of the delta form factors of the
    /// cells that show each element (a point shooter at the patch centre).
    Hemisphere,
    /// Receiver-side (Baum, Rushmeier & Winget 1989): Lambert's contour
    /// integral from each element's centre to the shooter patch, times the
    /// fraction of the cells its projection covers that show it.
    #[default]
    Hybrid,
}

/// Pieces per quad polygon edge the hemisphere rasteriser draws by default
/// (chosen by `radiosity bench`; see README "Performance").
pub const DEFAULT_RASTER_PIECES: u32 = 1;

/// Shooters below this fraction of the emitted power draw the coarse
/// hemisphere (`--coarse-below`; README "Coarse hemispheres for weak shooters").
pub const DEFAULT_COARSE_BELOW: f64 = 3e-3;

/// How a piece's cells are found on the hemisphere (`--projection`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Projection {
    /// A conservative cell rectangle per piece, and an exact per-cell ray
    /// test in the fragment shader (depth written per cell).
    #[default]
    Exact,
    /// Pieces cut into triangles fine enough that each edge's curved image
    /// is within a tolerance of its chord, projected in the vertex shader;
    /// fixed-function rasterisation and depth.
    Tessellated,
}

/// Default tolerance of the tessellated projection, in cells.
pub const DEFAULT_TESSELLATION_TOLERANCE: f32 = 0.1;

/// Everything a render can be told.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    /// Hemisphere resolution.
    pub resolution: Resolution,
    /// How form factors are evaluated.
    pub form_factor: FormFactorMethod,
    /// When to stop.
    pub stop: StopRule,
    /// How to subdivide.
    pub mesh: MeshSettings,
    /// How cells are found: exact per-cell test, or tessellation.
    pub projection: Projection,
    /// The tessellated projection's tolerance (cells between an edge's
    /// curved image and its chords).
    pub tessellation_tolerance: f32,
    /// What the hemisphere rasteriser draws: quad polygons as at most N x N
    /// pieces (the element is found per fragment), or every element (0).
    pub raster_pieces: u32,
    /// How the hemisphere is tiled and over which rank grid. Under MPI the
    /// grid comes from the rank count and only the tile size is used; in one
    /// process every rank's tiles are drawn in turn (one tile by default).
    pub layout: Option<TileLayout>,
    /// Tile size in cells (width along theta, height along phi) when running on
    /// several ranks; 1 x 1 is the paper's per-cell interleave.
    pub tile: (u32, u32),
    /// How ranks exchange form factors.
    pub exchange: Exchange,
    /// Image width in pixels (0: no image).
    pub width: u32,
    /// Image height (from the camera's aspect ratio when `None`).
    pub height: Option<u32>,
    /// Smooth or flat shading.
    pub shading: Shading,
    /// Add the ambient term to the image and the reported radiosities.
    pub ambient: bool,
    /// Keep form-factor rows of patches that have shot, so a patch that
    /// shoots again costs no rasterisation (results are identical either way).
    pub cache_rows: bool,
    /// Split a hybrid shot into one hemisphere per group of shooter elements
    /// where a near receiver is partly hidden from the shooter's centre.
    pub split_shots: bool,
    /// The hemisphere resolution of weak shooters (see `coarse_below`);
    /// `None`: half `resolution` along each axis (a quarter of the cells).
    pub coarse: Option<Resolution>,
    /// Shooters whose unshot power is below this fraction of the emitted
    /// power draw their hemisphere at `coarse` (0: every shot at `resolution`).
    pub coarse_below: f64,
    /// Shooters overshoot by rho times the ambient term (Feda & Purgathofer
    /// 1992): fewer shots to the same error, not less time on lavapipe (see
    /// [`crate::solver`]; off by default).
    pub overshoot: bool,
    /// Draw element edges over the image.
    pub wireframe: bool,
    /// Where and how often to save the solve's state (`None`: never).
    pub checkpoint: Option<CheckpointPlan>,
    /// Set (by a signal handler, say) to stop after the current shot: the
    /// state goes to the checkpoint and the result so far is returned.
    pub interrupt: Option<Arc<AtomicBool>>,
    /// Continue from this saved state instead of starting afresh.
    pub resume: Option<Arc<Checkpoint>>,
}

/// Where a solve saves its state.
#[derive(Clone, Debug)]
pub struct CheckpointPlan {
    /// The checkpoint file (replaced atomically each time).
    pub path: std::path::PathBuf,
    /// Save every this often (`None`: only when interrupted).
    pub every: Option<Duration>,
}

impl RenderOptions {
    /// The hemisphere resolution weak shooters draw at, if there is a coarse
    /// tier: `coarse`, or half `resolution` along each axis but no coarser
    /// than 64 x 256 (weak shooters at 48 x 192 or 32 x 128 leave the 64
    /// cubes above 1 %: README "Coarse hemispheres for weak shooters"), when
    /// `coarse_below` is above 0 and it has fewer cells than `resolution`.
    pub fn coarse_tier(&self) -> Option<Resolution> {
        let res = self.resolution;
        let coarse = self.coarse.unwrap_or(Resolution {
            rows: (res.rows / 2).max(64),
            cols: (res.cols / 2).max(256),
        });
        (self.coarse_below > 0.0 && coarse.cells() < res.cells()).then_some(coarse)
    }
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            resolution: Resolution::default(),
            form_factor: FormFactorMethod::default(),
            stop: StopRule::default(),
            mesh: MeshSettings::default(),
            raster_pieces: DEFAULT_RASTER_PIECES,
            projection: Projection::Exact,
            tessellation_tolerance: DEFAULT_TESSELLATION_TOLERANCE,
            layout: None,
            tile: (1, 1),
            exchange: Exchange::Hemispheres,
            width: 512,
            height: None,
            shading: Shading::Smooth,
            ambient: true,
            cache_rows: true,
            split_shots: true,
            overshoot: false,
            coarse: None,
            coarse_below: DEFAULT_COARSE_BELOW,
            wireframe: false,
            checkpoint: None,
            interrupt: None,
            resume: None,
        }
    }
}

/// Why a render failed.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// The GPU failed.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// A setting is unusable.
    #[error("invalid setting: {0}")]
    Settings(String),
    /// A checkpoint could not be written or does not fit this render.
    #[error("checkpoint: {0}")]
    Checkpoint(String),
}

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
    /// Rectangles drawn.
    pub rects: u64,
    /// Shots answered from the form-factor row cache (no rasterisation).
    pub cached: u64,
    /// Shots split into one hemisphere per group of shooter elements.
    pub split: u64,
    /// Shots drawn at the coarse resolution (weak shooters).
    pub coarse: u64,
}

/// Memory the form-factor row cache may use, in bytes per rank (summed over
/// ranks before each decision, so every rank keeps or drops a row alike).
pub const ROW_CACHE_BYTES: u64 = 1 << 30;

/// Form factors by rasterising the hemisphere on the GPU, tile by tile, and
/// exchanging them between ranks as DESIGN.md section 3 describes. Returns
/// the form factors of this rank's elements only.
pub struct GpuFormFactors<'a> {
    gpu: &'a Gpu,
    mesh: &'a Mesh,
    comm: &'a dyn Collectives,
    /// The hemisphere at the shot resolution, and at the coarse one for weak
    /// shooters (see [`RenderOptions::coarse_below`]).
    tiers: Vec<Tier>,
    /// Shooters with less unshot power than this (W, sum over RGB) draw the
    /// coarse tier's hemisphere.
    coarse_below: f64,
    /// The tier the last hemisphere was drawn in.
    last_tier: usize,
    exchange: Exchange,
    method: FormFactorMethod,
    /// Whether this rank owns each element.
    owned: Vec<bool>,
    /// Rank owning each element (sparse exchange).
    element_rank: Vec<u32>,
    /// This rank's cell values, packed for the all-gather (reused every shot).
    packed: Vec<u32>,
    acc: FormFactorAccumulator,
    items: Vec<u32>,
    pairs: Vec<(u32, u64)>,
    /// Time spent so far.
    pub timings: PhaseTimes,
    /// This rank's busy time (everything but waiting in collectives) per shot.
    pub busy: Vec<f64>,
    /// Per patch, from its first uncached hybrid shot: this rank's receivers'
    /// penumbra and total shares (see `refine::PatchStats`).
    pub penumbra: Vec<[u64; 2]>,
    /// Form-factor rows of patches that have shot, for when they shoot again
    /// (the same shooter gives the same row, so a hit changes no result).
    /// Keyed by shooter, hemisphere centre and tier: a weak shot of a patch
    /// that first shot strong draws (once) at the coarse tier, so that the
    /// cache, and a resumed solve's empty one, change no number.
    cache: std::collections::HashMap<RowKey, Row>,
    /// The last row computed, until it is known whether it fits.
    pending: Option<(RowKey, Row)>,
    /// Whether shots split where visibility varies across the shooter.
    split: bool,
    /// Bytes the cache holds over all ranks, and may hold.
    cache_bytes: u64,
    cache_budget: u64,
}

/// A cached row's shooter patch, hemisphere centre (f32 bits) and tier.
type RowKey = (u32, [u32; 3], u8);

/// Everything of a hemisphere that depends on its resolution.
struct Tier {
    raster: HemisphereRasterizer,
    layout: TileLayout,
    /// What one cell adds to the element it shows, per row: its delta form
    /// factor in fixed point (hemisphere) or one visible cell (hybrid).
    weights: Vec<u64>,
    /// Cells (row-major indices) of each rank's tiles (hemisphere exchange).
    cells_of: Vec<Vec<u32>>,
    /// How many cells each rank owns (known to all, so never exchanged).
    cell_counts: Vec<usize>,
    /// The whole hemisphere's cells, assembled from every rank's.
    full: Vec<u32>,
}

impl Tier {
    /// Uploads the mesh and builds the pipelines for resolution `res`.
    fn new(
        gpu: &Gpu,
        mesh: &Mesh,
        opts: &RenderOptions,
        res: Resolution,
        ranks: usize,
        extent: f32,
    ) -> Result<Self, RenderError> {
        let n = ranks;
        let layout = if n > 1 {
            let (px, py) = rank_grid(n);
            TileLayout {
                tile_w: opts.tile.0,
                tile_h: opts.tile.1,
                px,
                py,
            }
        } else {
            opts.layout.unwrap_or_else(|| TileLayout::whole(res))
        };
        if layout.tile_w == 0 || layout.tile_h == 0 || layout.px == 0 || layout.py == 0 {
            return Err(RenderError::Settings(format!(
                "tile layout {layout:?} has a zero size"
            )));
        }
        let mut raster =
            HemisphereRasterizer::new(&gpu.device, mesh, res, opts.raster_pieces, extent)?;
        if opts.projection == Projection::Tessellated {
            raster.use_tessellation(&gpu.device, opts.tessellation_tolerance)?;
        }
        let hybrid = opts.form_factor == FormFactorMethod::Hybrid;
        raster.set_count_coverage(hybrid);
        let weights = if hybrid {
            vec![crate::formfactor::VISIBLE_ONE; res.rows as usize]
        } else {
            res.delta_form_factors_fixed()
        };
        let mut cells_of = vec![Vec::new(); n];
        if n > 1 && layout.ranks() as usize == n {
            for p in 0..res.rows {
                for t in 0..res.cols {
                    let (x, y) = layout.owner(p, t);
                    cells_of[(y * layout.px + x) as usize].push(p * res.cols + t);
                }
            }
        }
        Ok(Self {
            raster,
            layout,
            weights,
            cell_counts: cells_of.iter().map(Vec::len).collect(),
            cells_of,
            full: vec![crate::hemisphere::EMPTY; res.cells()],
        })
    }
}

impl<'a> GpuFormFactors<'a> {
    /// Uploads the mesh and builds the pipelines. With one process and a
    /// multi-rank `layout`, every rank's tiles are drawn here in turn.
    pub fn new(
        gpu: &'a Gpu,
        mesh: &'a Mesh,
        opts: &RenderOptions,
        comm: &'a dyn Collectives,
        extent: f32,
    ) -> Result<Self, RenderError> {
        let n = comm.size();
        let mut tiers = vec![Tier::new(gpu, mesh, opts, opts.resolution, n, extent)?];
        if let Some(res) = opts.coarse_tier() {
            tiers.push(Tier::new(gpu, mesh, opts, res, n, extent)?);
        }
        let rank = comm.rank();
        let element_rank: Vec<u32> = mesh
            .elements
            .iter()
            .map(|e| (e.patch as usize % n) as u32)
            .collect();
        let owned = element_rank.iter().map(|&r| r as usize == rank).collect();
        Ok(Self {
            gpu,
            mesh,
            comm,
            tiers,
            coarse_below: opts.coarse_below * mesh.emitted_power(),
            last_tier: 0,
            exchange: opts.exchange,
            method: opts.form_factor,
            owned,
            element_rank,
            packed: Vec::new(),
            acc: FormFactorAccumulator::new(mesh.elements.len()),
            items: Vec::new(),
            pairs: Vec::new(),
            timings: PhaseTimes::default(),
            busy: Vec::new(),
            penumbra: vec![[0, 0]; mesh.patches.len()],
            cache: Default::default(),
            pending: None,
            split: opts.split_shots,
            cache_bytes: 0,
            cache_budget: if opts.cache_rows {
                ROW_CACHE_BYTES * n as u64
            } else {
                0
            },
        })
    }

    /// Bytes of the row computed by the last shot that the cache has not
    /// decided on yet (this rank's share).
    pub fn pending_bytes(&self) -> u64 {
        self.pending.as_ref().map_or(0, |(_, r)| r.bytes() as u64)
    }

    /// The tier a shooter of unshot power `power` draws in: the coarse one
    /// (when there is one) below [`RenderOptions::coarse_below`].
    fn tier_for(&self, power: f64) -> usize {
        if self.tiers.len() > 1 && power < self.coarse_below {
            1
        } else {
            0
        }
    }

    /// Draws the hemisphere of `shooter` at `centre` (every rank its tiles)
    /// in tier `tier`, exchanges, and leaves this rank's per-element sums in
    /// `self.pairs`. Returns the time spent in the exchange.
    fn hemisphere(
        &mut self,
        shooter: u32,
        centre: glam::Vec3,
        tier: usize,
    ) -> Result<Duration, GpuError> {
        let frame = self.mesh.shooter_frame_at(shooter, centre);
        self.last_tier = tier;
        let layout = self.tiers[tier].layout;
        let exchange = if self.comm.size() == 1 && layout.ranks() > 1 {
            // One process standing in for a rank grid: draw every rank's tiles.
            for ry in 0..layout.py {
                for rx in 0..layout.px {
                    self.draw(&frame, (rx, ry))?;
                    self.add_own();
                }
            }
            Duration::ZERO
        } else if self.comm.size() == 1 {
            self.draw(&frame, (0, 0))?;
            self.add_own();
            Duration::ZERO
        } else {
            let rank = self.comm.rank() as u32;
            self.draw(&frame, (rank % layout.px, rank / layout.px))?;
            self.exchange()
        };
        if self.acc.take_overflow() {
            return Err(GpuError::Failed(format!(
                "the fixed-point form-factor sums of shooter {shooter} overflowed 64 bits"
            )));
        }
        self.acc.drain_fixed(&mut self.pairs);
        Ok(exchange)
    }

    /// Keeps the pending row if the cache has room for `all_ranks_bytes`
    /// (the pending bytes summed over ranks, the same number on every rank).
    pub fn settle_cache(&mut self, all_ranks_bytes: u64) {
        if let Some((key, row)) = self.pending.take() {
            if self.cache_bytes + all_ranks_bytes <= self.cache_budget {
                self.cache_bytes += all_ranks_bytes;
                self.cache.insert(key, row);
            }
        }
    }

    /// The rasteriser at the shot resolution (for inspection: proxies, resolution).
    pub fn rasterizer(&self) -> &HemisphereRasterizer {
        &self.tiers[0].raster
    }

    /// The tile layout in use.
    pub fn layout(&self) -> TileLayout {
        self.tiers[0].layout
    }

    /// The item buffer of the last hemisphere this rank drew, and its resolution.
    pub fn last_items(&self) -> (&[u32], Resolution) {
        (&self.items, self.tiers[self.last_tier].raster.resolution())
    }

    fn draw(&mut self, frame: &crate::mesh::ShooterFrame, own: (u32, u32)) -> Result<(), GpuError> {
        let tier = &mut self.tiers[self.last_tier];
        let stats = tier.raster.render(
            &self.gpu.device,
            &self.gpu.queue,
            frame,
            &tier.layout,
            own,
            &mut self.items,
        )?;
        self.timings.bounds += stats.bounds;
        self.timings.rects += stats.rects as u64;
        self.timings.rasterise += stats.rasterise;
        self.timings.read_back += stats.readback;
        Ok(())
    }

    /// Adds this rank's cells of the last drawing to the accumulator: each
    /// cell's weight to the element it shows and, for hybrid form factors,
    /// every element's covered cells.
    fn add_own(&mut self) {
        let tier = &self.tiers[self.last_tier];
        let cols = tier.raster.resolution().cols as usize;
        self.acc
            .add_cells(&self.items, cols, 0, &tier.weights, None);
        self.add_coverage();
    }

    fn add_coverage(&mut self) {
        for (id, c) in self.tiers[self.last_tier].raster.coverage_pairs() {
            self.acc.add(id, c);
        }
    }

    /// Adds this rank's cells to the accumulator, exchanges, and leaves the
    /// sums for this rank's elements in the accumulator.
    fn exchange(&mut self) -> Duration {
        let (comm, owned) = (self.comm, &self.owned[..]);
        let mut exchange = Duration::ZERO;
        match self.exchange {
            Exchange::Hemispheres => {
                let tier = &mut self.tiers[self.last_tier];
                let cols = tier.raster.resolution().cols as usize;
                self.packed.clear();
                self.packed.extend(
                    tier.cells_of[comm.rank()]
                        .iter()
                        .map(|&i| self.items[i as usize]),
                );
                let t = Instant::now();
                let all = comm.all_gather_u32(&self.packed, Some(&tier.cell_counts));
                exchange += t.elapsed();
                for (cells, values) in tier.cells_of.iter().zip(&all) {
                    for (&c, &v) in cells.iter().zip(values) {
                        tier.full[c as usize] = v;
                    }
                }
                self.acc
                    .add_cells(&tier.full, cols, 0, &tier.weights, Some(owned));
                if self.method == FormFactorMethod::Hybrid {
                    // Coverage counts are per rank: send them to the owners.
                    exchange += send_to_owners(
                        comm,
                        &self.element_rank,
                        &mut self.acc,
                        tier.raster.coverage_pairs(),
                    );
                }
            }
            Exchange::FormFactors => {
                self.add_own();
                let t = Instant::now();
                comm.reduce_broadcast_sum(self.acc.dense_mut());
                exchange += t.elapsed();
                self.acc.retouch(&self.owned);
            }
            Exchange::Sparse => {
                self.add_own();
                self.acc.drain_fixed(&mut self.pairs);
                exchange += send_to_owners(
                    comm,
                    &self.element_rank,
                    &mut self.acc,
                    self.pairs.iter().copied(),
                );
            }
        }
        exchange
    }
}

/// Sends (element, fixed-point value) pairs to the ranks that own the
/// elements and adds what arrives to `acc`. Returns the time in the collective.
fn send_to_owners(
    comm: &dyn Collectives,
    element_rank: &[u32],
    acc: &mut FormFactorAccumulator,
    pairs: impl Iterator<Item = (u32, u64)>,
) -> Duration {
    let mut outgoing = vec![Vec::new(); comm.size()];
    for (id, v) in pairs {
        outgoing[element_rank[id as usize] as usize].push((id, v));
    }
    let t = Instant::now();
    let incoming = comm.all_to_all_pairs(&outgoing);
    let spent = t.elapsed();
    for (id, v) in incoming {
        acc.add(id, v);
    }
    spent
}

impl FormFactorSource for GpuFormFactors<'_> {
    type Error = GpuError;

    fn form_factors(
        &mut self,
        shooter: u32,
        region: &ShotRegion,
        out: &mut Vec<Transfer>,
    ) -> Result<(), GpuError> {
        let start = Instant::now();
        let centre = region.centre;
        let tier = self.tier_for(region.power);
        let key = (shooter, centre.to_array().map(f32::to_bits), tier as u8);
        if let Some(row) = self.cache.get(&key) {
            row.combine(region, out);
            self.timings.cached += 1;
            self.timings.sum += start.elapsed();
            self.busy.push(start.elapsed().as_secs_f64());
            return Ok(());
        }
        let before = self.timings.bounds + self.timings.rasterise + self.timings.read_back;
        if tier > 0 {
            self.timings.coarse += 1;
        }
        let mut exchange = self.hemisphere(shooter, centre, tier)?;
        let row = match self.method {
            FormFactorMethod::Hemisphere => Row {
                columns: 1,
                ids: self.pairs.iter().map(|p| p.0).collect(),
                values: self
                    .pairs
                    .iter()
                    .map(|p| p.1 as f64 / crate::hemisphere::FIXED_ONE)
                    .collect(),
                ..Row::default()
            },
            FormFactorMethod::Hybrid => {
                let m = self.mesh.patches[shooter as usize].elements.len();
                let columns = if m <= crate::formfactor::MAX_SHOOTER_COLUMNS {
                    m
                } else {
                    1
                };
                let mut row =
                    crate::formfactor::hybrid_row(self.mesh, shooter, &self.pairs, 0..columns);
                if let Some(p) = self.penumbra.get_mut(shooter as usize) {
                    *p = [row.partial + row.near_hidden, row.total + row.near_hidden];
                }
                // Refinement by need: a near receiver partly hidden from the
                // shooter's centre means visibility varies across the
                // shooter, so each group of its elements looks for itself.
                let mut split = self.split
                    && columns > 1
                    && crate::formfactor::needs_split(row.near_hidden, row.total);
                if self.split && columns > 1 && self.comm.size() > 1 {
                    // Each rank has its receivers' share: sum them (exactly).
                    let t = Instant::now();
                    let all = self
                        .comm
                        .all_gather_f64(&[row.near_hidden as f64, row.total as f64]);
                    let (h, tot) = all
                        .chunks_exact(2)
                        .fold((0u64, 0u64), |(h, t), c| (h + c[0] as u64, t + c[1] as u64));
                    split = crate::formfactor::needs_split(h, tot);
                    exchange += t.elapsed();
                }
                if split {
                    let mut merged = Row {
                        columns,
                        ..Row::default()
                    };
                    for (group, at) in crate::formfactor::split_groups(self.mesh, shooter, columns)
                    {
                        exchange += self.hemisphere(shooter, at, tier)?;
                        merged.merge(&crate::formfactor::hybrid_row(
                            self.mesh,
                            shooter,
                            &self.pairs,
                            group,
                        ));
                    }
                    self.timings.split += 1;
                    row = merged;
                }
                row
            }
        };
        row.combine(region, out);
        if self.cache_budget > 0 {
            self.pending = Some((key, row));
            if self.comm.size() == 1 {
                // One process: the decision needs nobody else.
                self.settle_cache(self.pending_bytes());
            }
        }
        let total = start.elapsed();
        let drawn = self.timings.bounds + self.timings.rasterise + self.timings.read_back - before;
        self.timings.exchange += exchange;
        self.timings.sum += total.saturating_sub(exchange + drawn);
        self.busy.push((total - exchange).as_secs_f64());
        Ok(())
    }
}

/// Where a solve stands, for progress displays.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Shots so far.
    pub shots: u64,
    /// Unshot power fraction now.
    pub unshot_fraction: f64,
    /// Time since the solve started.
    pub elapsed: Duration,
}

/// The result of [`render`].
pub struct Rendered {
    /// The discretised scene.
    pub mesh: Mesh,
    /// Radiosity per element (no ambient term).
    pub radiosity: Vec<[f64; 3]>,
    /// Image size and linear radiance pixels (top row first), if an image was asked for.
    pub image: Option<(u32, u32, Vec<[f32; 3]>)>,
    /// The report.
    pub report: Report,
    /// The solve stopped early because it was interrupted.
    pub interrupted: bool,
}

/// Solves `scene` in this process and renders its camera view. `load_time` is
/// reported as the load phase.
pub fn render(
    gpu: &Gpu,
    scene: &Scene,
    opts: &RenderOptions,
    load_time: Duration,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Rendered, RenderError> {
    let single = Single::default();
    // With one rank this process is rank 0, which always gets the result.
    render_on(gpu, scene, opts, &single, load_time, progress)?
        .ok_or_else(|| RenderError::Settings("no result on rank 0".into()))
}

fn stats_vector(
    t: &PhaseTimes,
    select: Duration,
    update: Duration,
    comm: &dyn Collectives,
    trace: Traffic,
) -> Vec<f64> {
    let mut traffic = comm.traffic();
    // The trace's gathers (and the refinement passes, passed in with them)
    // are not the solve's exchange.
    traffic.sent -= trace.sent.min(traffic.sent);
    traffic.received -= trace.received.min(traffic.received);
    vec![
        select.as_secs_f64(),
        t.bounds.as_secs_f64(),
        t.rasterise.as_secs_f64(),
        t.read_back.as_secs_f64(),
        t.exchange.as_secs_f64(),
        t.sum.as_secs_f64(),
        update.as_secs_f64(),
        traffic.sent as f64,
        traffic.received as f64,
        t.rects as f64,
    ]
}

/// What the shooting loop asks of its caller between shots.
trait LoopHooks {
    /// After every shot, on every rank, with the unshot fraction before it.
    fn after_shot(&mut self, solver: &Solver, unshot_fraction: f64);
    /// This rank's say for the next shot: bit 0 stop now (interrupted),
    /// bit 1 save the state (only rank 0's bit 1 counts, so ranks agree).
    fn flags(&self) -> u32 {
        0
    }
    /// Saves the state; every rank calls it at the same point.
    fn checkpoint(&mut self, _solver: &Solver) -> Result<(), RenderError> {
        Ok(())
    }
}

/// Hooks from a closure run after every shot (no checkpoints).
struct AfterShot<F>(F);

impl<F: FnMut(&Solver, f64)> LoopHooks for AfterShot<F> {
    fn after_shot(&mut self, solver: &Solver, unshot_fraction: f64) {
        (self.0)(solver, unshot_fraction)
    }
}

/// What a shooting loop measured, besides the solver's state.
#[derive(Default)]
struct LoopStats {
    /// It stopped because a rank was interrupted.
    interrupted: bool,
    select: Duration,
    update: Duration,
    shot_times: Vec<Duration>,
    /// Power each patch shot, summed (sum over RGB; the same on every rank).
    patch_power: Vec<f64>,
}

/// Shoots until `stop` says done: progressive refinement (DESIGN.md section
/// 2) over the ranks of `comm`. `hooks` run on every rank after every shot
/// (the trace, progress displays) and say when to save the state or stop.
/// The loop also ends when the strongest shooter left has less than `floor` power.
fn shoot_until(
    mesh: &Mesh,
    stop: &StopRule,
    floor: f64,
    comm: &dyn Collectives,
    source: &mut GpuFormFactors,
    solver: &mut Solver,
    hooks: &mut dyn LoopHooks,
) -> Result<LoopStats, RenderError> {
    let (rank, ranks) = (comm.rank(), comm.size());
    let mut stats = LoopStats {
        patch_power: vec![0.0; mesh.patches.len()],
        ..LoopStats::default()
    };
    let (mut landed_fixed, mut last_power) = (0.0f64, None::<f64>);
    let mut ff = Vec::new();
    loop {
        let shot_start = Instant::now();
        // One collective per shot decides both the stop rule and the shooter:
        // every rank's unshot power (fixed point, exact in f64 below 2^53) and
        // its best patch.
        const W: usize = 17;
        // Only overshooting needs the ambient term during the loop.
        let net = if solver.overshoot() {
            solver.local_net_unshot()
        } else {
            [0; 3]
        };
        let mut mine = [0.0; W];
        mine[0] = solver.local_unshot_fixed() as f64;
        mine[1] = -1.0;
        if let Some(c) = solver.local_candidate() {
            mine[1..10].copy_from_slice(&[
                c.patch as f64,
                c.power,
                c.unshot[0],
                c.unshot[1],
                c.unshot[2],
                c.centre.x as f64,
                c.centre.y as f64,
                c.centre.z as f64,
                c.weighted as u8 as f64,
            ]);
            mine[13] = c.lit;
        }
        mine[10] = landed_fixed;
        mine[11] = source.pending_bytes() as f64;
        mine[12] = hooks.flags() as f64;
        // Signed unshot power per channel, fixed point: exact in f64 below 2^53.
        mine[14..17].copy_from_slice(&net.map(|x| x as f64));
        let all = comm.all_gather_f64(&mine);
        if ranks > 1 {
            source.settle_cache(all.chunks_exact(W).map(|c| c[11] as u64).sum());
        }
        if let Some(power) = last_power.take() {
            // What the last shot landed, over every rank's elements (fixed
            // point, so the sum is exact and the same on every rank).
            let landed = all.chunks_exact(W).map(|c| c[10] as u64).sum::<u64>() as f64 / UNSHOT_ONE;
            solver.note_retention(power, landed);
        }
        let unshot_fraction =
            all.chunks_exact(W).map(|c| c[0] as u64).sum::<u64>() as f64 / UNSHOT_ONE;
        // Between shots the state decides everything that follows: the
        // place to save it, or to stop when any rank was interrupted.
        let interrupted = all.chunks_exact(W).any(|c| c[12] as u32 & 1 != 0);
        if interrupted || all[12] as u32 & 2 != 0 {
            hooks.checkpoint(solver)?;
        }
        if interrupted {
            stats.interrupted = true;
            break;
        }
        if solver.done_at(stop, unshot_fraction) {
            break;
        }
        let best = Candidate::best(all.chunks_exact(W).filter(|c| c[1] >= 0.0).map(|c| {
            Candidate {
                patch: c[1] as u32,
                power: c[2],
                unshot: [c[3], c[4], c[5]],
                // f32 -> f64 -> f32 is exact, so every rank gets the owner's point.
                centre: glam::Vec3::new(c[6] as f32, c[7] as f32, c[8] as f32),
                weighted: c[9] != 0.0,
                lit: c[13],
            }
        }));
        stats.select += shot_start.elapsed();
        let Some(best) = best.filter(|b| b.power >= floor) else {
            break;
        };
        // The whole solution's signed unshot power, summed exactly: every
        // rank gets the same ambient term, whatever their number.
        let mut net: NetUnshot = [0; 3];
        for c in all.chunks_exact(W) {
            for (n, x) in net.iter_mut().zip(&c[14..17]) {
                *n += *x as i64;
            }
        }
        let ambient = solver.ambient_from(net);
        let region = if best.weighted {
            // Only the owner knows what each of the shooter's elements
            // shoots: it tells the others (all know how many there are).
            let owner = best.patch as usize % ranks;
            let m = mesh.patches[best.patch as usize].elements.len();
            let mut mine = vec![0.0; 3 * m + 3];
            if rank == owner {
                let r = solver.shooting_region(best.patch, ambient);
                mine[..3].copy_from_slice(&r.shoot);
                for n in 0..m {
                    mine[3 + 3 * n..6 + 3 * n]
                        .copy_from_slice(r.elements.get(n).unwrap_or(&r.shoot));
                }
            }
            let all = comm.all_gather_f64(&mine);
            let theirs = &all[owner * (3 * m + 3)..(owner + 1) * (3 * m + 3)];
            let elements: Vec<[f64; 3]> = theirs[3..]
                .chunks_exact(3)
                .map(|x| [x[0], x[1], x[2]])
                .collect();
            let uniform = elements.iter().all(|e| *e == elements[0]);
            ShotRegion {
                centre: best.centre,
                power: best.power,
                shoot: [theirs[0], theirs[1], theirs[2]],
                elements: if uniform { Vec::new() } else { elements },
            }
        } else {
            solver.candidate_region(&best, ambient)
        };
        source.form_factors(best.patch, &region, &mut ff)?;
        let t = Instant::now();
        let shot = solver.shoot_candidate(&best, &region, &ff);
        let dt = t.elapsed();
        // This rank's elements' share of what landed, told at the next collective.
        // Each element's F is rounded on its own, so the sum does not depend
        // on how elements are split between ranks.
        let own: u64 = ff
            .iter()
            .filter(|t| solver.owns(mesh.elements[t.element as usize].patch))
            .map(|t| (t.form_factor.clamp(0.0, 1.0) * UNSHOT_ONE).round() as u64)
            .sum();
        landed_fixed = own as f64;
        last_power = Some(shot.shot_power);
        stats.update += dt;
        stats.patch_power[best.patch as usize] += shot.power;
        if let Some(b) = source.busy.last_mut() {
            *b += dt.as_secs_f64();
        }
        stats.shot_times.push(shot_start.elapsed());
        hooks.after_shot(solver, unshot_fraction);
    }
    Ok(stats)
}

/// The final solve's hooks: the trace, progress, checkpoints and interrupts.
struct SolveHooks<'a, 'p> {
    comm: &'a dyn Collectives,
    nodes: &'a [String],
    ambient: bool,
    solve_start: Instant,
    trace: Trace,
    progress: &'p mut dyn FnMut(&Progress),
    plan: Option<&'a CheckpointPlan>,
    interrupt: Option<&'a AtomicBool>,
    last_save: Instant,
    /// What every checkpoint says besides the state, the trace and the time.
    header: Header,
}

impl LoopHooks for SolveHooks<'_, '_> {
    fn after_shot(&mut self, solver: &Solver, unshot_fraction: f64) {
        if self.trace.due(solver.shots()) {
            self.trace.record(
                self.comm,
                solver,
                self.nodes,
                self.ambient,
                self.solve_start,
            );
        }
        if self.comm.rank() == 0 {
            (self.progress)(&Progress {
                shots: solver.shots(),
                unshot_fraction,
                elapsed: self.solve_start.elapsed(),
            });
        }
    }

    fn flags(&self) -> u32 {
        let mut flags = 0;
        if self.interrupt.is_some_and(|i| i.load(Ordering::Relaxed)) {
            flags |= 1;
        }
        let every = self.plan.and_then(|p| p.every);
        if self.comm.rank() == 0 && every.is_some_and(|e| self.last_save.elapsed() >= e) {
            flags |= 2;
        }
        flags
    }

    fn checkpoint(&mut self, solver: &Solver) -> Result<(), RenderError> {
        let started = Instant::now();
        self.last_save = started;
        let Some(plan) = self.plan else {
            return Ok(());
        };
        // Rank 0 assembles the whole state and writes it; every rank learns
        // whether that worked, so none waits for a rank that gave up.
        let written = match gather_whole(self.comm, solver, true) {
            Some(whole) => {
                let mut header = self.header.clone();
                header.seconds = self
                    .solve_start
                    .elapsed()
                    .saturating_sub(self.trace.spent)
                    .as_secs_f64();
                header.trace = self.trace.points.clone();
                let c = Checkpoint {
                    header,
                    state: whole.state(),
                };
                crate::output::write_atomic(&plan.path, &c.to_bytes()).map_err(|e| e.to_string())
            }
            _ => Ok(()),
        };
        self.comm.all_ok(written).map_err(|failed| {
            RenderError::Checkpoint(if failed.is_empty() {
                "rank 0 could not write it".into()
            } else {
                failed
                    .iter()
                    .map(|(r, m)| format!("rank {r}: {m}"))
                    .collect::<Vec<_>>()
                    .join("; ")
            })
        })?;
        if self.comm.rank() == 0 {
            log::info!(
                "saved the state after {} shots to {}",
                solver.shots(),
                plan.path.display()
            );
        }
        // Saving is bookkeeping, like the trace: not solve time.
        self.trace.spent += started.elapsed();
        Ok(())
    }
}

/// Gathers every rank's share of `solver` to rank 0 and assembles the whole
/// solution there (`None` on the other ranks): radiosities, unshot
/// radiosities, shots, retention, overshooting, and with `elements` the
/// elements' unshot radiosities (a checkpoint needs them, and so does the
/// unshot fraction under overshooting). Every rank must call it.
fn gather_whole<'m>(
    comm: &dyn Collectives,
    solver: &Solver<'m>,
    elements: bool,
) -> Option<Solver<'m>> {
    let (b, u) = solver.local_state();
    let (gb, gu) = (comm.gather_f64(&b), comm.gather_f64(&u));
    let ge = if elements {
        comm.gather_f64(&solver.local_element_unshot())
    } else {
        None
    };
    let mut whole = Solver::new(solver.mesh());
    whole.assemble(&gb?, &gu?);
    if let Some(e) = &ge {
        whole.assemble_element_unshot(e);
    }
    whole.set_overshoot(solver.overshoot());
    whole.set_shots(solver.shots());
    whole.copy_retention(solver);
    Some(whole)
}

/// What a checkpoint must match to be resumed here: the scene's geometry,
/// materials and subdivision, and every setting that changes the numbers
/// (not the rank count, tiles or exchange, which do not).
fn fingerprint(scene: &Scene, opts: &RenderOptions) -> String {
    let mut geometry = Vec::new();
    for p in &scene.polygons {
        let floats = p.vertices.iter().flat_map(|v| v.to_array());
        for x in floats.chain(p.reflectance).chain(p.emission) {
            geometry.extend_from_slice(&x.to_bits().to_le_bytes());
        }
        geometry.extend_from_slice(format!("{} {:?};", p.node, p.subdivision).as_bytes());
    }
    let settings = format!(
        "{} {:?} {:?} {} {} {:?} {} {:?} {}",
        opts.resolution,
        opts.form_factor,
        mesh_settings(opts),
        opts.split_shots,
        opts.overshoot,
        opts.projection,
        opts.tessellation_tolerance,
        opts.coarse_tier().map(|r| r.to_string()),
        opts.coarse_below
    );
    crate::checkpoint::fingerprint(&[
        &geometry,
        settings.as_bytes(),
        scene.nodes.join("\n").as_bytes(),
    ])
}

/// The mesh settings a render uses: refinement by need only with hybrid
/// form factors (hemisphere sums do not measure penumbrae) and without a
/// fixed `--patch-size`.
pub fn mesh_settings(opts: &RenderOptions) -> MeshSettings {
    let mut m = opts.mesh;
    if opts.form_factor != FormFactorMethod::Hybrid || m.patch_size.is_some() {
        m.refine = 0;
    }
    m
}

/// The mesh a render solves: refinement by need (`crate::refine`), i.e.
/// coarse solves, each followed by a decision that doubles some polygons'
/// patch grids, until nothing asks for more or [`mesh_settings`]' `refine`
/// passes have run. Returns the mesh, what the passes did and the
/// per-polygon patch-grid factors. Every rank calls this with the same arguments.
pub fn refined_mesh(
    gpu: &Gpu,
    scene: &Scene,
    opts: &RenderOptions,
    comm: &dyn Collectives,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Mesh, Refinement, Vec<u32>), RenderError> {
    let settings = mesh_settings(opts);
    let n = scene.polygons.len();
    let mut factors = vec![1u32; n];
    let mut summary = Refinement::default();
    let levels = settings.refine;
    let mut shooters = vec![false; n];
    for pass in 0..levels {
        let mesh = Mesh::build_refined(scene, &settings, &factors);
        if pass == 0 {
            summary.start = [mesh.patches.len(), mesh.elements.len()];
        }
        let mut source = GpuFormFactors::new(gpu, &mesh, opts, comm, scene.extent())?;
        let started = Instant::now();
        // No overshooting here: the passes only measure the shooters, and
        // the mesh they choose is then the same with or without it.
        let mut solver = Solver::partitioned(&mesh, comm.rank(), comm.size());
        // Shots after the last one strong enough to be refined change nothing.
        let floor = refine::SHOOTER_TOL * solver.emitted_power();
        let stats = shoot_until(
            &mesh,
            &opts.stop,
            floor,
            comm,
            &mut source,
            &mut solver,
            &mut AfterShot(|s: &Solver, u: f64| {
                if comm.rank() == 0 {
                    progress(&Progress {
                        shots: s.shots(),
                        unshot_fraction: u,
                        elapsed: started.elapsed(),
                    });
                }
            }),
        )?;
        summary.passes += 1;
        summary.shots += solver.shots();
        // Every rank saw its own receivers' penumbrae: sum them (exactly).
        let mut penumbra: Vec<u64> = source.penumbra.iter().flatten().copied().collect();
        comm.reduce_broadcast_sum(&mut penumbra);
        let patches: Vec<PatchStats> = stats
            .patch_power
            .iter()
            .zip(penumbra.chunks_exact(2))
            .map(|(&power, p)| PatchStats {
                power,
                penumbra: [p[0], p[1]],
            })
            .collect();
        let decided = refine::decide(&mesh, &patches, solver.emitted_power());
        summary.seconds += started.elapsed().as_secs_f64();
        let mut changed = 0;
        for ((f, refined), &d) in factors.iter_mut().zip(&mut shooters).zip(&decided) {
            if d {
                *f *= 2;
                *refined = true;
                changed += 1;
            }
        }
        summary.shooter_refinements += changed;
        if comm.rank() == 0 {
            log::info!(
                "refinement pass {}: {} patches, {} shots; {changed} polygons get finer shooters",
                pass + 1,
                mesh.patches.len(),
                solver.shots(),
            );
        }
        if changed == 0 {
            break;
        }
    }
    summary.shooter_polygons = shooters.iter().filter(|&&x| x).count() as u32;
    Ok((
        Mesh::build_refined(scene, &settings, &factors),
        summary,
        factors,
    ))
}

/// Solves `scene` over the ranks of `comm` (every rank calls this with the
/// same arguments) and, on rank 0, renders the camera view and the report.
/// Other ranks get `Ok(None)`.
pub fn render_on(
    gpu: &Gpu,
    scene: &Scene,
    opts: &RenderOptions,
    comm: &dyn Collectives,
    load_time: Duration,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Option<Rendered>, RenderError> {
    opts.resolution.validate().map_err(RenderError::Settings)?;
    if opts.stop.threshold.is_nan() || opts.stop.threshold < 0.0 {
        return Err(RenderError::Settings(format!(
            "threshold {} must be >= 0",
            opts.stop.threshold
        )));
    }
    let (rank, ranks) = (comm.rank(), comm.size());
    let mut timings = Timings {
        load: load_time.as_secs_f64(),
        ..Default::default()
    };
    let t = Instant::now();
    let fingerprint = fingerprint(scene, opts);
    let (mesh, refinement, factors) = match &opts.resume {
        Some(c) => {
            if c.header.fingerprint != fingerprint {
                return Err(RenderError::Checkpoint(format!(
                    "it was saved from {} with other geometry or settings (resolution, form factors, subdivision and split shots must match)",
                    c.header.scene
                )));
            }
            let mesh = Mesh::build_refined(scene, &mesh_settings(opts), &c.header.factors);
            (mesh, c.header.refinement.clone(), c.header.factors.clone())
        }
        None => refined_mesh(gpu, scene, opts, comm, progress)?,
    };
    // The passes' solves count as solve time, below.
    timings.mesh = (t.elapsed().as_secs_f64() - refinement.seconds).max(0.0);
    // Their exchanges are not the final solve's.
    let before = comm.traffic();
    if rank == 0 {
        log::info!(
            "{}: {} polygons, {} patches, {} elements",
            scene.name,
            scene.polygons.len(),
            mesh.patches.len(),
            mesh.elements.len()
        );
    }

    let t = Instant::now();
    let mut source = GpuFormFactors::new(gpu, &mesh, opts, comm, scene.extent())?;
    timings.setup = t.elapsed().as_secs_f64();
    let layout = source.layout();

    let mut solver = Solver::partitioned(&mesh, rank, ranks);
    solver.set_overshoot(opts.overshoot);
    let mut trace = Trace::default();
    // The refinement passes (and, resuming, the solve before the checkpoint)
    // count as solve time (set-up excluded), so the trace's times are the
    // honest time to each accuracy.
    let mut so_far = refinement.seconds;
    if let Some(c) = &opts.resume {
        solver.restore(&c.state).map_err(RenderError::Checkpoint)?;
        trace.resume(c.header.trace.clone(), c.state.shots);
        so_far = c.header.seconds;
        if rank == 0 {
            log::info!(
                "resuming after {} shots ({so_far:.2} s of solve)",
                c.state.shots
            );
        }
    }
    let solve_start = Instant::now()
        .checked_sub(Duration::from_secs_f64(so_far))
        .unwrap_or_else(Instant::now);
    let mut hooks = SolveHooks {
        comm,
        nodes: &scene.nodes,
        ambient: opts.ambient,
        solve_start,
        trace,
        progress,
        plan: opts.checkpoint.as_ref(),
        interrupt: opts.interrupt.as_deref(),
        last_save: Instant::now(),
        header: Header {
            scene: scene.name.clone(),
            fingerprint,
            counts: [mesh.patches.len(), mesh.elements.len()],
            factors,
            refinement: refinement.clone(),
            seconds: 0.0,
            trace: Vec::new(),
        },
    };
    let stats = shoot_until(
        &mesh,
        &opts.stop,
        0.0,
        comm,
        &mut source,
        &mut solver,
        &mut hooks,
    )?;
    let trace = hooks.trace;
    let interrupted = stats.interrupted;
    let LoopStats {
        select,
        update,
        mut shot_times,
        ..
    } = stats;
    timings.solve = (solve_start.elapsed() - trace.spent).as_secs_f64();
    let shots = solver.shots();

    // Gather the solution and every rank's statistics to rank 0.
    let (b, u) = solver.local_state();
    let gathered_b = comm.gather_f64(&b);
    let gathered_u = comm.gather_f64(&u);
    // With overshooting the unshot fraction sums elements' |unshot|.
    let gathered_e = if opts.overshoot {
        comm.gather_f64(&solver.local_element_unshot())
    } else {
        None
    };
    let stats = comm.gather_f64(&stats_vector(
        &source.timings,
        select,
        update,
        comm,
        Traffic {
            sent: trace.traffic.sent + before.sent,
            received: trace.traffic.received + before.received,
        },
    ));
    let busy = comm.gather_f64(&source.busy);
    let timings_src = source.timings;
    drop(source);
    let (Some(gathered_b), Some(gathered_u), Some(stats), Some(busy)) =
        (gathered_b, gathered_u, stats, busy)
    else {
        return Ok(None);
    };
    solver.assemble(&gathered_b, &gathered_u);
    if let Some(e) = &gathered_e {
        solver.assemble_element_unshot(e);
    }
    solver.set_shots(shots);

    timings.select_shooter = select.as_secs_f64();
    timings.update = update.as_secs_f64();
    timings.bounds = timings_src.bounds.as_secs_f64();
    timings.rects_per_shot = timings_src.rects as f64 / shots.max(1) as f64;
    timings.cached_shots = timings_src.cached;
    timings.split_shots = timings_src.split;
    timings.coarse_shots = timings_src.coarse;
    timings.rasterise = timings_src.rasterise.as_secs_f64();
    timings.read_back = timings_src.read_back.as_secs_f64();
    timings.exchange = timings_src.exchange.as_secs_f64();
    timings.sum_form_factors = timings_src.sum.as_secs_f64();
    shot_times.sort();
    timings.median_shot_ms = shot_times
        .get(shot_times.len() / 2)
        .map_or(0.0, |d| d.as_secs_f64() * 1e3);

    let t = Instant::now();
    let camera = scene.camera.unwrap_or_else(|| scene.default_camera());
    let height = opts.height.unwrap_or_else(|| {
        (opts.width as f32 / camera.aspect.unwrap_or(1.0))
            .round()
            .max(1.0) as u32
    });
    let image = if opts.width > 0 {
        let radiance: Vec<[f32; 3]> = solver
            .display_radiosity(opts.ambient)
            .iter()
            .map(|b| b.map(|x| (x / std::f64::consts::PI) as f32))
            .collect();
        let view = ViewSettings {
            width: opts.width,
            height,
            shading: opts.shading,
            supersample: 2,
            wireframe: opts.wireframe,
        };
        Some((
            opts.width,
            height,
            render_view(&gpu.device, &gpu.queue, &mesh, &radiance, &camera, &view)?,
        ))
    } else {
        None
    };
    timings.image = t.elapsed().as_secs_f64();

    let per_rank: Vec<RankStats> = stats
        .iter()
        .enumerate()
        .map(|(r, v)| RankStats {
            rank: r,
            select_shooter: v[0],
            bounds: v[1],
            rasterise: v[2],
            read_back: v[3],
            exchange: v[4],
            sum_form_factors: v[5],
            update: v[6],
            bytes_sent: v[7] as u64,
            bytes_received: v[8] as u64,
        })
        .collect();
    let parallel = Parallel::new(
        ranks,
        layout,
        opts.exchange,
        opts.resolution,
        mesh.elements.len(),
        shots,
        per_rank,
        LoadBalance::from_busy(&busy),
    );
    let solve_seconds = timings.solve;
    let mut report = build_report(
        scene,
        &mesh,
        opts,
        &solver,
        gpu,
        [opts.width, height],
        timings,
        parallel,
    );
    report.convergence = trace.finish(&report, solve_seconds);
    report.refinement = refinement;
    if interrupted {
        report.warnings.push(match &opts.checkpoint {
            Some(plan) => format!(
                "interrupted after {shots} shots; the state is saved in {}: resume with --resume {}",
                plan.path.display(),
                plan.path.display()
            ),
            None => format!("interrupted after {shots} shots (no checkpoint to resume from)"),
        });
    }
    let radiosity = solver.display_radiosity(opts.ambient);
    drop(solver);
    Ok(Some(Rendered {
        mesh,
        radiosity,
        image,
        report,
        interrupted,
    }))
}

/// The report of a (gathered) solution: settings, counts, progress and surfaces.
#[allow(clippy::too_many_arguments)]
pub fn build_report(
    scene: &Scene,
    mesh: &Mesh,
    opts: &RenderOptions,
    solver: &Solver,
    gpu: &Gpu,
    image_size: [u32; 2],
    timings: Timings,
    parallel: Parallel,
) -> Report {
    let unshot_fraction = solver.unshot_fraction();
    Report {
        scene: scene.name.clone(),
        settings: Settings {
            resolution: opts.resolution,
            form_factor: opts.form_factor,
            threshold: opts.stop.threshold,
            max_shots: opts.stop.max_shots,
            mesh: mesh_settings(opts),
            raster_pieces: opts.raster_pieces,
            projection: opts.projection,
            tessellation_tolerance: (opts.projection == Projection::Tessellated)
                .then_some(opts.tessellation_tolerance),
            image_size,
            shading: opts.shading,
            ambient: opts.ambient,
            overshoot: opts.overshoot,
            coarse: opts
                .coarse_tier()
                .map(|c| (c.to_string(), opts.coarse_below)),
        },
        device: gpu.describe(),
        refinement: Refinement::default(),
        bake: None,
        counts: Counts {
            polygons: scene.polygons.len(),
            patches: mesh.patches.len(),
            elements: mesh.elements.len(),
            cells: opts.resolution.cells(),
            ranks: parallel.ranks,
        },
        shots: solver.shots(),
        unshot_fraction,
        converged: unshot_fraction <= opts.stop.threshold,
        emitted_power: solver.emitted_power(),
        timings,
        parallel,
        surfaces: report::surfaces(mesh, &scene.nodes, &solver.display_radiosity(opts.ambient)),
        convergence: Vec::new(),
        warnings: scene.warnings.clone(),
    }
}

/// The report's convergence trace as the solve goes: when to record, and the
/// points so far (rank 0's; other ranks only take part in the gathers).
#[derive(Default)]
pub struct Trace {
    /// Recorded points.
    pub points: Vec<TracePoint>,
    /// The next shot count to record after the first 32.
    next: u64,
    /// Time spent gathering and summarising (left out of the solve time).
    pub spent: Duration,
    /// Bytes the trace's gathers moved (left out of the exchange's traffic).
    pub traffic: Traffic,
}

impl Trace {
    /// Whether a point is due after `shots` shots: every shot up to 32, then
    /// at every power of two and at counts growing by 2^(1/4). The
    /// same on every rank, since it depends on the shot count alone.
    pub fn due(&mut self, shots: u64) -> bool {
        if shots <= 32 || shots.is_power_of_two() {
            return true;
        }
        if shots >= self.next.max(33) {
            self.next = ((shots as f64) * 2f64.powf(0.25)).ceil() as u64;
            return true;
        }
        false
    }

    /// Records the solution now. Every rank must call this at the same shot;
    /// with several ranks the owners' radiosities are gathered to rank 0.
    pub fn record(
        &mut self,
        comm: &dyn Collectives,
        solver: &Solver,
        nodes: &[String],
        ambient: bool,
        solve_start: Instant,
    ) {
        let seconds = solve_start
            .elapsed()
            .saturating_sub(self.spent)
            .as_secs_f64();
        self.record_at(comm, solver, nodes, ambient, seconds);
    }

    /// [`Trace::record`] with the solve time given (e.g. a viewer's, which
    /// leaves its pauses out).
    pub fn record_at(
        &mut self,
        comm: &dyn Collectives,
        solver: &Solver,
        nodes: &[String],
        ambient: bool,
        seconds: f64,
    ) {
        let t = Instant::now();
        let before = comm.traffic();
        let summary = if comm.size() == 1 {
            Some((
                report::surfaces(solver.mesh(), nodes, &solver.display_radiosity(ambient)),
                solver.unshot_fraction(),
            ))
        } else {
            // With overshooting the unshot fraction sums elements' |unshot|.
            gather_whole(comm, solver, solver.overshoot()).map(|whole| {
                (
                    report::surfaces(solver.mesh(), nodes, &whole.display_radiosity(ambient)),
                    whole.unshot_fraction(),
                )
            })
        };
        if let Some((surfaces, unshot_fraction)) = summary {
            self.points.push(TracePoint {
                shots: solver.shots(),
                seconds,
                unshot_fraction,
                surfaces,
            });
        }
        self.spent += t.elapsed();
        let after = comm.traffic();
        self.traffic.sent += after.sent - before.sent;
        self.traffic.received += after.received - before.received;
    }

    /// The trace with its last point made equal to the final result.
    pub fn finish(self, report: &Report, seconds: f64) -> Vec<TracePoint> {
        self.ending_with(report, seconds)
    }

    /// Continues a trace saved after `shots` shots (its points, and the
    /// schedule of the points to come, as if it had run here).
    pub fn resume(&mut self, points: Vec<TracePoint>, shots: u64) {
        self.points = points;
        for s in 1..=shots {
            self.due(s);
        }
    }

    /// The points so far, the last made equal to `report` (which the trace keeps going after).
    pub fn ending_with(&self, report: &Report, seconds: f64) -> Vec<TracePoint> {
        let mut points = self.points.clone();
        if points.last().is_some_and(|p| p.shots == report.shots) {
            points.pop();
        }
        points.push(TracePoint {
            shots: report.shots,
            seconds,
            unshot_fraction: report.unshot_fraction,
            surfaces: report.surfaces.clone(),
        });
        points
    }
}

/// The `parallel` section of a one-process solve.
pub fn single_process(res: Resolution, elements: usize, shots: u64) -> Parallel {
    Parallel::new(
        1,
        TileLayout::whole(res),
        Exchange::Hemispheres,
        res,
        elements,
        shots,
        Vec::new(),
        LoadBalance::default(),
    )
}
