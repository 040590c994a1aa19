//! The JSON report (DESIGN.md section 6).

use crate::hemisphere::Resolution;
use crate::mesh::Mesh;
use serde::Serialize;

/// Everything a run did, for people and for tests.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// The scene path or built-in name.
    pub scene: String,
    /// Every setting that affects the result.
    pub settings: Settings,
    /// The adapter the form factors were rasterised on.
    pub device: String,
    /// Sizes of the problem (the final mesh).
    pub counts: Counts,
    /// How the mesh was refined by need before the final solve.
    pub refinement: Refinement,
    /// Shots taken.
    pub shots: u64,
    /// Unshot power / emitted power at the end.
    pub unshot_fraction: f64,
    /// Whether the threshold was reached (rather than the shot limit).
    pub converged: bool,
    /// Total emitted power (sum over RGB), W.
    pub emitted_power: f64,
    /// Where the emitted power went: absorbed, unshot, escaped, and the
    /// balance (absorbed + unshot) / emitted, 1 in a closed scene.
    pub energy: crate::solver::Energy,
    /// The lights that are not surfaces (`KHR_lights_punctual`, `--sun`),
    /// as the solve used them (radiometric units).
    pub lights: Vec<LightSummary>,
    /// The uniform sky's radiance (`--sky`), W sr^-1 m^-2 per channel.
    pub sky: Option<[f64; 3]>,
    /// The environment map (`--sky-map`): its file, size, turn and strength.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sky_map: Option<String>,
    /// Wall-clock seconds per phase (rank 0's; every rank's are in `parallel`).
    pub timings: Timings,
    /// Ranks, their grid and tiles, the exchange, per-rank phases and traffic, load balance.
    pub parallel: Parallel,
    /// Per glTF node: area and area-weighted mean radiosity (with the
    /// ambient term unless `settings.ambient` is false).
    pub surfaces: Vec<Surface>,
    /// The solution as it converged: at every one of the first 32 shots,
    /// then at every power of two and at shot counts growing by 2^(1/4),
    /// and at the end (the last point equals `shots` and `surfaces`).
    pub convergence: Vec<TracePoint>,
    /// The baked glTF (`--bake`), if one was written: its path and colour
    /// scale (COLOR_0 = min(1, B / pi x scale)).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bake: Option<crate::bake::Baked>,
    /// Non-fatal problems met on the way.
    pub warnings: Vec<String>,
}

/// One light as the report gives it.
#[derive(Clone, Debug, Serialize)]
pub struct LightSummary {
    /// Its name (the glTF light's, its node's, or `sun`).
    pub name: String,
    /// `point`, `spot` or `directional`.
    pub kind: &'static str,
    /// Where it is, relative to the scene's origin (its first vertex, as
    /// every position the renderer keeps); unused for a directional light.
    pub position: [f32; 3],
    /// The unit vector it shines along.
    pub direction: [f32; 3],
    /// W/sr (point, spot) or W/m^2 (directional), per channel.
    pub intensity: [f64; 3],
    /// A spot's inner and outer cone half-angles, radians.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cones: Option<[f32; 2]>,
    /// The power it emits, W (sum over RGB; none for a directional light).
    pub power: Option<f64>,
}

impl LightSummary {
    /// The summary of `light`.
    pub fn of(light: &crate::scene::Light) -> Self {
        let cones = match light.kind {
            crate::scene::LightKind::Spot { inner, outer } => Some([inner, outer]),
            _ => None,
        };
        LightSummary {
            name: light.name.clone(),
            kind: light.kind.name(),
            position: light.position.to_array(),
            direction: light.direction.to_array(),
            intensity: light.intensity,
            cones,
            power: light.power(),
        }
    }
}

impl Report {
    /// The first number that is not finite where a number belongs (a
    /// radiosity, area, fraction or power), named; `None` when all are.
    pub fn non_finite(&self) -> Option<String> {
        let surfaces = |s: &[Surface], at: &str| {
            s.iter().find_map(|x| {
                (!x.area.is_finite() || x.radiosity.iter().any(|v| !v.is_finite()))
                    .then(|| format!("{at}surface '{}'", x.node))
            })
        };
        if !self.unshot_fraction.is_finite() {
            return Some("unshot_fraction".into());
        }
        if !self.emitted_power.is_finite() {
            return Some("emitted_power".into());
        }
        surfaces(&self.surfaces, "").or_else(|| {
            self.convergence.iter().find_map(|p| {
                if !(p.unshot_fraction.is_finite() && p.seconds.is_finite()) {
                    return Some(format!("convergence point at {} shots", p.shots));
                }
                surfaces(
                    &p.surfaces,
                    &format!("convergence point at {} shots, ", p.shots),
                )
            })
        })
    }
}

/// The settings of a run.
#[derive(Clone, Debug, Serialize)]
pub struct Settings {
    /// Hemisphere resolution (R_phi x R_theta).
    pub resolution: Resolution,
    /// How form factors were evaluated.
    pub form_factor: crate::settings::FormFactorMethod,
    /// Stop at this unshot fraction.
    pub threshold: f64,
    /// Stop after this many shots.
    pub max_shots: u64,
    /// Subdivision settings.
    pub mesh: crate::mesh::MeshSettings,
    /// Pieces per quad polygon edge drawn by the hemisphere rasteriser (0: every element).
    pub raster_pieces: u32,
    /// Whether one rank left undrawn the polygons nearer ones hide (the
    /// same bits either way).
    pub occlusion_cull: bool,
    /// Whether the ranks dealt the polygons' bounds (`auto`, `on`, `off`;
    /// the same bits either way).
    pub deal_bounds: crate::settings::DealBounds,
    /// How cells were found: `exact` or `tessellated`.
    pub projection: crate::settings::Projection,
    /// The tessellated projection's tolerance in cells (null with `exact`).
    pub tessellation_tolerance: Option<f32>,
    /// Where the hemispheres' cells were drawn: `device` or `cpu` (`auto`
    /// resolved for the adapter).
    pub rasteriser: crate::settings::Rasteriser,
    /// Image size.
    pub image_size: [u32; 2],
    /// Smooth or flat.
    pub shading: crate::gpu::Shading,
    /// Shadow rays per emitter per image sample of the traced direct light
    /// (0: the direct light interpolated from the solution).
    pub shadow_rays: u32,
    /// Whether the sky is drawn where camera rays leave the scene.
    pub background: bool,
    /// Final gather rays per pixel of the image's indirect light (0: interpolated).
    pub gather: u32,
    /// Whether the ambient term (the unshot light's estimate) is in the
    /// image and in the reported radiosities.
    pub ambient: bool,
    /// Which ambient term (see [`crate::settings::AmbientTerm`]).
    pub ambient_term: crate::settings::AmbientTerm,
    /// The hemisphere resolution of weak shooters, and below what fraction
    /// of the emitted power a shooter is weak (absent: every shot at `resolution`).
    pub coarse: Option<(String, f64)>,
    /// Shooters below this fraction of the emitted power shoot along the
    /// ambient term's transport (0: none do).
    pub transport_below: f64,
}

/// One point of the convergence trace.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct TracePoint {
    /// Shots taken.
    pub shots: u64,
    /// Seconds of solve since the first shot (device set-up and the trace's
    /// own gathering excluded).
    pub seconds: f64,
    /// Unshot power / emitted power.
    pub unshot_fraction: f64,
    /// Per node, exactly as the top-level `surfaces`; absent at the points
    /// [`thin_trace`] leaves without them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub surfaces: Vec<Surface>,
    /// The refinement pass (from 0) whose coarse solution this is; absent
    /// for the final solve's points. A pass's `shots` count its own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pass: Option<u32>,
}

/// The most per-node values a report's convergence trace keeps (about 230
/// bytes each in the written JSON): a scene of 4098 nodes traced at 49
/// points wrote a 45 MB report; within this, 2 MB of trace.
pub const TRACE_VALUES: usize = 8192;

/// Keeps the per-node values of at most [`TRACE_VALUES`] / nodes points
/// (at least the first and the last), spread evenly over the points, which
/// the trace spaces evenly in log shots; every point keeps its shots, time
/// and unshot fraction. A trace within the budget is left as it is.
pub fn thin_trace(points: &mut [TracePoint]) {
    let nodes = points.iter().map(|p| p.surfaces.len()).max().unwrap_or(0);
    let n = points.len();
    if n <= 2 || nodes * n <= TRACE_VALUES {
        return;
    }
    let keep = (TRACE_VALUES / nodes).clamp(2, n);
    let kept: std::collections::BTreeSet<usize> =
        (0..keep).map(|i| i * (n - 1) / (keep - 1)).collect();
    for (i, p) in points.iter_mut().enumerate() {
        if !kept.contains(&i) {
            p.surfaces = Vec::new();
        }
    }
}

/// Problem sizes.
#[derive(Clone, Debug, Serialize)]
pub struct Counts {
    /// Polygons (both sides of double-sided surfaces count).
    pub polygons: usize,
    /// Shooting patches.
    pub patches: usize,
    /// Receiving elements.
    pub elements: usize,
    /// Hemisphere cells N_M.
    pub cells: usize,
    /// MPI ranks.
    pub ranks: usize,
}

/// What refinement by need did (`crate::refine`) before the final solve.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct Refinement {
    /// Coarse solves run (each until no shooter left could be refined).
    pub passes: u32,
    /// Shots those passes took (not counted in `shots`).
    pub shots: u64,
    /// Seconds they took (included in `timings.solve` and the trace's times),
    /// their meshes' ambient transports included.
    pub seconds: f64,
    /// Of `seconds`: the ambient transports' estimates (each pass's mesh
    /// has its own, so it shows its solution from its first shot).
    #[serde(default)]
    pub transport_seconds: f64,
    /// Polygons whose patch grid (shooters) was refined at least once.
    pub shooter_polygons: u32,
    /// Doublings of patch grids for shooters, over all polygons and passes.
    pub shooter_refinements: u32,
    /// Polygons whose patch grid was refined at least once because its
    /// receivers held their light unevenly (`refine::RECEIVER_TOL`).
    #[serde(default)]
    pub receiver_polygons: u32,
    /// Doublings of patch grids for uneven receivers (a polygon refined for
    /// both reasons counts in both), over all polygons and passes.
    #[serde(default)]
    pub receiver_refinements: u32,
    /// Polygons refined because the image would shade their indirect
    /// light badly (`refine::shading_error`).
    #[serde(default)]
    pub shading_polygons: u32,
    /// Doublings of patch grids for that reason, over all polygons and passes.
    #[serde(default)]
    pub shading_refinements: u32,
    /// Patches and elements of the final mesh.
    #[serde(default)]
    pub end: [usize; 2],
    /// Patches and elements of the first (coarsest) mesh.
    pub start: [usize; 2],
    /// A pass was interrupted: the final mesh is that pass's, refined no
    /// further, and the solve went on from (or stopped at) its solution.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub interrupted: bool,
}

/// Seconds spent per phase.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Timings {
    /// Reading and parsing the scene.
    pub load: f64,
    /// Subdividing.
    pub mesh: f64,
    /// Creating the device, pipelines and buffers.
    pub setup: f64,
    /// The whole shooting loop.
    pub solve: f64,
    /// Choosing shooters (summed over shots).
    pub select_shooter: f64,
    /// Finding the cell rectangles to draw, on the CPU (summed over shots).
    pub bounds: f64,
    /// Mean rectangles found in view per shot (bounded; some then culled).
    pub rects_per_shot: f64,
    /// Mean rectangles per shot left undrawn as hidden behind nearer
    /// geometry (occlusion culling; rank 0's, of `rects_per_shot`).
    #[serde(default)]
    pub occluded_per_shot: f64,
    /// Mean proxies per shot the occlusion cull left out before bounding
    /// them, not among `rects_per_shot` (one process on one core walks
    /// the polygons nearest first and skips what nearer ones hide; rank 0's).
    #[serde(default)]
    pub skipped_per_shot: f64,
    /// Shots whose form factors came from the row cache (a patch shooting again).
    pub cached_shots: u64,
    /// The row cache each rank could hold, bytes: what its memory budget
    /// (`--memory`) left after the scene, the mesh and the drawing, at most 1 GiB.
    pub row_cache_bytes: u64,
    /// Shots split into one hemisphere per group of shooter elements
    /// (visibility varied across the shooter).
    pub split_shots: u64,
    /// Shots drawn at the coarse hemisphere resolution (weak shooters;
    /// rasterised shots only).
    pub coarse_shots: u64,
    /// Shots along the ambient term's transport (`--transport-below`).
    pub transport_shots: u64,
    /// Drawing hemispheres on the GPU and waiting for them (summed over shots).
    pub rasterise: f64,
    /// Reading item buffers back (summed over shots).
    pub read_back: f64,
    /// Exchanging form factors between ranks (summed over shots).
    pub exchange: f64,
    /// Summing delta form factors per element (summed over shots).
    pub sum_form_factors: f64,
    /// Of `sum_form_factors`: the shadow rays to receivers smaller than a
    /// hemisphere cell that no cell covered (summed over shots).
    pub far_receivers: f64,
    /// The far receivers' centre rays cast on a thread of their own while
    /// the hemisphere was drawn (summed over shots; thread time, beside
    /// the drawing's wall time, not in `sum_form_factors`).
    #[serde(default)]
    pub far_receivers_ahead: f64,
    /// Distributing radiosity (summed over shots).
    pub update: f64,
    /// Of `solve`: estimating the ambient term's transport, once, at its
    /// start (`--ambient carried`; 0 otherwise).
    pub ambient: f64,
    /// Rendering and writing the image.
    pub image: f64,
    /// Median milliseconds per shot of the final solve.
    pub median_shot_ms: f64,
    /// Shots of the final solve whose row was drawn ahead, beside an
    /// earlier shot (`render::ahead`).
    pub drawn_ahead_shots: u64,
    /// Mean milliseconds per shot of the final solve: where rows are drawn
    /// ahead (`render::ahead`) a shot whose row is ready takes little and
    /// one that draws takes a row's time, so the mean, not the median,
    /// says what a shot costs.
    pub mean_shot_ms: f64,
}

/// How the solve was spread over ranks, and what that cost.
#[derive(Clone, Debug, Serialize)]
pub struct Parallel {
    /// MPI ranks.
    pub ranks: usize,
    /// The Px x Py rank grid the hemisphere's tiles are dealt to.
    pub rank_grid: [u32; 2],
    /// Tile size in cells (along theta, along phi).
    pub tile: [u32; 2],
    /// The form-factor exchange (of a shot's hemisphere split over the
    /// ranks; unused by batched shots).
    pub exchange: crate::parallel::Exchange,
    /// Shooters a step (`--batch`): above 1 each rank draws whole
    /// hemispheres for its turns of a batch and sends the rows to their
    /// elements' owners, instead of the exchange.
    pub batch: usize,
    /// Per rank: seconds per phase (summed over shots) and bytes exchanged.
    pub per_rank: Vec<RankStats>,
    /// Batched shots' rows in shot order (the first 10 000 shots'; empty
    /// unbatched).
    pub rows: Vec<BatchRow>,
    /// Bytes per shot received by a rank, by the paper's formulas: hemispheres
    /// 4 N_M (N - 1) / N (over N stages); form factors one stage's 8 N_El
    /// (64-bit fixed point; the reduction and broadcast take ceil(log2 N) + 1
    /// such stages inside MPI); sparse has no closed form (null).
    pub formula_bytes_per_shot: Option<f64>,
    /// Mean bytes received per rank per shot, measured.
    pub measured_bytes_per_shot: f64,
    /// Load balance epsilon = T_min / T_max of each shot's busy time over ranks.
    pub load_balance: LoadBalance,
    /// The same from each shot's busy CPU seconds (outside collective calls):
    /// with more ranks than cores, the balance of the work itself.
    pub load_balance_cpu: LoadBalance,
}

/// How a solve was spread over its ranks: how many, the hemisphere's tiles
/// over their grid, the exchange, and the hemisphere's resolution.
#[derive(Clone, Copy, Debug)]
pub struct Decomposition {
    /// Ranks.
    pub ranks: usize,
    /// The tiles and the rank grid.
    pub layout: crate::hemisphere::TileLayout,
    /// How form factors met.
    pub exchange: crate::parallel::Exchange,
    /// The hemisphere's resolution.
    pub resolution: Resolution,
}

impl Parallel {
    /// Assembles the parallel section of a solve spread as `d` says, over
    /// `elements` elements, `shots` shots, with every rank's statistics
    /// and the shots' load balance.
    pub fn new(
        d: Decomposition,
        elements: usize,
        shots: u64,
        per_rank: Vec<RankStats>,
        load_balance: LoadBalance,
    ) -> Self {
        use crate::parallel::Exchange;
        let Decomposition {
            ranks,
            layout,
            exchange,
            resolution: res,
        } = d;
        let n = ranks as f64;
        let formula = match exchange {
            _ if ranks == 1 => Some(0.0),
            Exchange::Hemispheres => Some(4.0 * res.cells() as f64 * (n - 1.0) / n),
            Exchange::FormFactors => Some(8.0 * elements as f64),
            Exchange::Sparse => None,
        };
        let received: f64 = per_rank.iter().map(|r| r.bytes_received as f64).sum();
        Self {
            ranks,
            rank_grid: [layout.px, layout.py],
            tile: [layout.tile_w, layout.tile_h],
            exchange,
            batch: 1,
            per_rank,
            rows: Vec::new(),
            formula_bytes_per_shot: formula,
            measured_bytes_per_shot: received / n / shots.max(1) as f64,
            load_balance,
            load_balance_cpu: load_balance,
        }
    }
}

/// One rank's costs.
#[derive(Clone, Debug, Serialize)]
pub struct RankStats {
    /// The rank.
    pub rank: usize,
    /// Seconds choosing shooters (including the global reduction).
    pub select_shooter: f64,
    /// Seconds finding cell rectangles.
    pub bounds: f64,
    /// Seconds drawing.
    pub rasterise: f64,
    /// Seconds reading item buffers back.
    pub read_back: f64,
    /// Seconds in the form-factor exchange.
    pub exchange: f64,
    /// Seconds summing form factors.
    pub sum_form_factors: f64,
    /// Seconds updating radiosities.
    pub update: f64,
    /// Bytes sent in exchanges.
    pub bytes_sent: u64,
    /// Bytes received in exchanges.
    pub bytes_received: u64,
    /// Work counted (not timed), summed over the shots this rank drew:
    /// rectangles drawn (each rank bounds and draws every rectangle that
    /// holds one of its cells), or, where the ranks deal the bounds, the
    /// rectangles of the polygons it bounded (they sum to one rank's)...
    pub rects: u64,
    /// ... hemisphere cells in its tiles (divided between the ranks) ...
    pub cells: u64,
    /// ... and receiving elements whose form factors it summed.
    pub receivers: u64,
    /// Proxies whose cell rectangle it computed (the bounds pass's work;
    /// over several ranks, the polygons of its deal).
    pub bounded: u64,
    /// Bytes it received agreeing with the other ranks on which hidden
    /// polygons to leave undrawn (the occlusion cull; not in `bytes_received`).
    pub occlusion_bytes_received: u64,
    /// Bytes of rectangles it received from the ranks that bounded them
    /// (the bounds' deal; not in `bytes_received`).
    pub rect_bytes_received: u64,
    /// This process's peak resident memory, bytes (Linux `VmHWM`; 0 where
    /// unknown), when the solve was gathered.
    pub peak_resident_bytes: u64,
    /// Process CPU seconds (every thread, the GPU driver's included) over
    /// the final solve: with more ranks than cores, wall times mix in the
    /// waits for a core and this does not.
    pub cpu_seconds: f64,
    /// ... of which inside collective calls (MPI polls while it waits), so
    /// `cpu_seconds - mpi_cpu_seconds` is the rank's own work. Every
    /// collective of the final solve counts: the exchange's, the occlusion
    /// cull's and the bounds' deal.
    pub mpi_cpu_seconds: f64,
    /// Collective calls in the final solve (the exchange's, the cull's and
    /// the deal's).
    pub mpi_calls: u64,
    /// Of `cpu_seconds`, drawing the rows of batched shots (0 unbatched):
    /// the work the ranks divide; the rest every rank does.
    pub rows_cpu_seconds: f64,
}

/// One row of a batched shot (`--batch`): which rank drew it, what the
/// assignment weighed it at and what it cost, so the performance model can
/// replay each batch's assignment on any number of ranks.
#[derive(Clone, Debug, Serialize)]
pub struct BatchRow {
    /// The solve's shot count when its batch began.
    pub batch_start: u64,
    /// Its place in the batch (round 1: in the batch's list of groups).
    pub index: u32,
    /// 0: a row (its first hemisphere, and, for a split shot, its
    /// assembly); 1: one group of a split shot, dealt in a second round
    /// (a batch waits for each round's slowest rank).
    pub round: u32,
    /// The rank that drew it.
    pub rank: usize,
    /// Its weight in the assignment (1 a fresh row, less at a coarse tier
    /// or in a rank's row cache).
    pub cost: f64,
    /// Process CPU seconds drawing it and packing it for its owners.
    pub cpu_seconds: f64,
}

/// This process's peak resident memory so far, bytes (`VmHWM` in
/// `/proc/self/status`; 0 where there is none).
pub fn peak_resident_bytes() -> u64 {
    proc_status_bytes("VmHWM:")
}

/// This process's resident memory now, bytes (`VmRSS`; 0 where there is none).
pub fn resident_bytes() -> u64 {
    proc_status_bytes("VmRSS:")
}

/// A `kB` line of `/proc/self/status`, in bytes.
fn proc_status_bytes(key: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix(key))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        })
        .map_or(0, |kb| kb * 1024)
}

/// Logs (at debug level) the resident and peak memory after `stage`: where
/// a big scene's memory goes (`RUST_LOG=radiosity=debug`).
pub fn log_memory(stage: &str) {
    log::debug!(
        "memory after {stage}: {:.0} MB resident, {:.0} MB peak",
        resident_bytes() as f64 / 1e6,
        peak_resident_bytes() as f64 / 1e6
    );
}

/// Statistics of epsilon = T_min / T_max over shots (1 is perfect balance).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct LoadBalance {
    /// Mean over shots.
    pub mean: f64,
    /// Best shot.
    pub max: f64,
    /// Worst shot.
    pub min: f64,
}

impl LoadBalance {
    /// From every rank's busy seconds per shot (`busy[rank][shot]`).
    pub fn from_busy(busy: &[Vec<f64>]) -> Self {
        let shots = busy.iter().map(Vec::len).min().unwrap_or(0);
        if shots == 0 {
            return Self {
                mean: 1.0,
                max: 1.0,
                min: 1.0,
            };
        }
        let eps: Vec<f64> = (0..shots)
            .map(|s| {
                let (lo, hi) = busy.iter().fold((f64::MAX, 0.0f64), |(lo, hi), b| {
                    (lo.min(b[s]), hi.max(b[s]))
                });
                if hi > 0.0 {
                    lo / hi
                } else {
                    1.0
                }
            })
            .collect();
        Self {
            mean: eps.iter().sum::<f64>() / shots as f64,
            max: eps.iter().cloned().fold(0.0, f64::max),
            min: eps.iter().cloned().fold(1.0, f64::min),
        }
    }
}

/// One glTF node's result.
#[derive(Clone, Debug, Serialize, serde::Deserialize, PartialEq)]
pub struct Surface {
    /// Node name.
    pub node: String,
    /// Area in m^2 of its front side (of a one-sided surface: all of it).
    pub area: f64,
    /// Area-weighted mean radiosity of its front side, W/m^2 per channel.
    pub radiosity: [f64; 3],
    /// The back side of a double-sided surface, reported apart (absent for
    /// one-sided surfaces).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub back: Option<Side>,
}

/// One side of a double-sided surface.
#[derive(Clone, Copy, Debug, Serialize, serde::Deserialize, PartialEq)]
pub struct Side {
    /// Area in m^2.
    pub area: f64,
    /// Area-weighted mean radiosity, W/m^2 per channel.
    pub radiosity: [f64; 3],
}

/// Per-node areas and area-weighted mean radiosities, the front and the
/// back of double-sided surfaces apart, of radiosities given element by
/// element in element order (no per-element vector needed: the trace
/// summarises a big scene at every point).
pub fn surfaces(
    mesh: &Mesh,
    nodes: &[String],
    radiosity: impl Iterator<Item = [f64; 3]>,
) -> Vec<Surface> {
    // [front, back] per node.
    let mut area = vec![[0.0f64; 2]; nodes.len()];
    let mut sum = vec![[[0.0f64; 3]; 2]; nodes.len()];
    for (e, b) in mesh.elements.iter().zip(radiosity) {
        let poly = &mesh.polygons[e.polygon as usize];
        let side = usize::from(poly.back_side);
        area[poly.node][side] += e.area;
        for c in 0..3 {
            sum[poly.node][side][c] += b[c] * e.area;
        }
    }
    let mean = |s: [f64; 3], a: f64| s.map(|x| if a > 0.0 { x / a } else { 0.0 });
    nodes
        .iter()
        .enumerate()
        .map(|(i, name)| Surface {
            node: name.clone(),
            area: area[i][0],
            radiosity: mean(sum[i][0], area[i][0]),
            back: (area[i][1] > 0.0).then(|| Side {
                area: area[i][1],
                radiosity: mean(sum[i][1], area[i][1]),
            }),
        })
        .collect()
}

/// Area-weighted mean and worst relative error per surface of `s` against
/// `reference` (each surface's error is the mean over its channels; nodes
/// with a zero reference radiosity, or missing from `s`, are skipped).
pub fn relative_error(s: &[Surface], reference: &[Surface]) -> (f64, f64) {
    let (mut sum, mut area, mut worst) = (0.0, 0.0, 0.0f64);
    for r in reference {
        let Some(x) = s.iter().find(|x| x.node == r.node) else {
            continue;
        };
        let mut e = 0.0;
        let mut n = 0;
        for c in 0..3 {
            if r.radiosity[c] > 0.0 {
                e += (x.radiosity[c] - r.radiosity[c]).abs() / r.radiosity[c];
                n += 1;
            }
        }
        if n == 0 {
            continue;
        }
        let e = e / n as f64;
        sum += e * r.area;
        area += r.area;
        worst = worst.max(e);
    }
    (if area > 0.0 { sum / area } else { 0.0 }, worst)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(shots: u64, nodes: usize) -> TracePoint {
        let surface = |k: usize| Surface {
            node: format!("n{k}"),
            area: 1.0,
            radiosity: [shots as f64; 3],
            back: None,
        };
        TracePoint {
            shots,
            seconds: shots as f64,
            unshot_fraction: 1.0 / shots as f64,
            surfaces: (0..nodes).map(surface).collect(),
            pass: None,
        }
    }

    #[test]
    fn a_big_trace_keeps_per_node_values_at_few_points_a_small_one_at_all() {
        let mut small: Vec<_> = (1..=80).map(|s| point(s, 10)).collect();
        let before = small.clone();
        thin_trace(&mut small);
        assert_eq!(small, before, "within the budget nothing changes");

        let nodes = 4000;
        let mut big: Vec<_> = (1..=80).map(|s| point(s, nodes)).collect();
        thin_trace(&mut big);
        let kept: Vec<_> = big.iter().filter(|p| !p.surfaces.is_empty()).collect();
        assert_eq!(kept.len(), TRACE_VALUES / nodes);
        assert!(kept.len() * nodes <= TRACE_VALUES);
        assert_eq!(kept.first().map(|p| p.shots), Some(1), "the first point");
        assert_eq!(kept.last().map(|p| p.shots), Some(80), "the last point");
        assert!(big
            .iter()
            .all(|p| p.unshot_fraction == 1.0 / p.shots as f64));
        // Thinned points say nothing of the nodes in JSON, and read back.
        let json = serde_json::to_string(&big[1]).expect("JSON");
        assert!(!json.contains("surfaces"), "{json}");
        let back: TracePoint = serde_json::from_str(&json).expect("reads back");
        assert_eq!(back, big[1]);
    }
}
