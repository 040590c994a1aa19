//! One render from start to finish: scene -> mesh -> form factors on the GPU ->
//! progressive refinement -> image and report. Used by the `radiosity` binary,
//! the tests and the viewer; it joins the modules but adds no maths of its own.

use crate::gpu::{render_view, Gpu, GpuError, HemisphereRasterizer, Shading, ViewSettings};
use crate::hemisphere::{FormFactorAccumulator, Resolution, TileLayout};
use crate::mesh::{Mesh, MeshSettings};
use crate::report::{self, Counts, Report, Settings, Timings};
use crate::scene::Scene;
use crate::solver::{FormFactorSource, Solver, StopRule};
use std::time::{Duration, Instant};

/// Everything a render can be told.
#[derive(Clone, Debug)]
pub struct RenderOptions {
    /// Hemisphere resolution.
    pub resolution: Resolution,
    /// When to stop.
    pub stop: StopRule,
    /// How to subdivide.
    pub mesh: MeshSettings,
    /// Rasterisation proxies per element edge (tessellation control).
    pub raster_split: u32,
    /// How the hemisphere is tiled and over which rank grid; every rank's
    /// tiles are drawn here in turn (one tile, one rank by default).
    pub layout: Option<TileLayout>,
    /// Image width in pixels (0: no image).
    pub width: u32,
    /// Image height (from the camera's aspect ratio when `None`).
    pub height: Option<u32>,
    /// Smooth or flat shading.
    pub shading: Shading,
    /// Add the ambient term to the image.
    pub ambient: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            resolution: Resolution::default(),
            stop: StopRule::default(),
            mesh: MeshSettings::default(),
            raster_split: 1,
            layout: None,
            width: 512,
            height: None,
            shading: Shading::Smooth,
            ambient: true,
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
}

/// Per-shot phase timings of the GPU form-factor source.
#[derive(Clone, Copy, Debug, Default)]
pub struct SourceTimings {
    /// Finding cell rectangles (CPU).
    pub bounds: Duration,
    /// Rectangles drawn.
    pub rects: u64,
    /// Drawing.
    pub rasterise: Duration,
    /// Reading back.
    pub read_back: Duration,
    /// Summing delta form factors.
    pub sum: Duration,
}

/// Form factors by rasterising the hemisphere on the GPU, tile by tile.
pub struct GpuFormFactors<'a> {
    gpu: &'a Gpu,
    mesh: &'a Mesh,
    raster: HemisphereRasterizer,
    layout: TileLayout,
    acc: FormFactorAccumulator,
    dff: Vec<u64>,
    items: Vec<u32>,
    /// Time spent so far, summed over shots.
    pub timings: SourceTimings,
}

impl<'a> GpuFormFactors<'a> {
    /// Uploads the mesh and builds the pipelines.
    pub fn new(
        gpu: &'a Gpu,
        mesh: &'a Mesh,
        res: Resolution,
        raster_split: u32,
        layout: Option<TileLayout>,
        extent: f32,
    ) -> Result<Self, RenderError> {
        let layout = layout.unwrap_or_else(|| TileLayout::whole(res));
        if layout.tile_w == 0 || layout.tile_h == 0 || layout.px == 0 || layout.py == 0 {
            return Err(RenderError::Settings(format!(
                "tile layout {layout:?} has a zero size"
            )));
        }
        let raster = HemisphereRasterizer::new(&gpu.device, mesh, res, raster_split, extent)?;
        Ok(Self {
            gpu,
            mesh,
            raster,
            layout,
            acc: FormFactorAccumulator::new(mesh.elements.len()),
            dff: res.delta_form_factors_fixed(),
            items: Vec::new(),
            timings: SourceTimings::default(),
        })
    }

    /// The rasteriser (for inspection: proxies, resolution).
    pub fn rasterizer(&self) -> &HemisphereRasterizer {
        &self.raster
    }

    /// The item buffer of the last rank drawn in the last shot.
    pub fn last_items(&self) -> &[u32] {
        &self.items
    }
}

impl FormFactorSource for GpuFormFactors<'_> {
    type Error = GpuError;

    fn form_factors(&mut self, shooter: u32, out: &mut Vec<(u32, f64)>) -> Result<(), GpuError> {
        let frame = self.mesh.shooter_frame(shooter);
        let cols = self.raster.resolution().cols as usize;
        for ry in 0..self.layout.py {
            for rx in 0..self.layout.px {
                let stats = self.raster.render(
                    &self.gpu.device,
                    &self.gpu.queue,
                    &frame,
                    &self.layout,
                    (rx, ry),
                    &mut self.items,
                )?;
                self.timings.bounds += stats.bounds;
                self.timings.rects += stats.rects as u64;
                self.timings.rasterise += stats.rasterise;
                self.timings.read_back += stats.readback;
                let t = Instant::now();
                self.acc.add_cells(&self.items, cols, 0, &self.dff);
                self.timings.sum += t.elapsed();
            }
        }
        let t = Instant::now();
        self.acc.drain_sorted(out);
        self.timings.sum += t.elapsed();
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
}

/// Solves `scene` and renders its camera view. `load_time` is reported as the load phase.
pub fn render(
    gpu: &Gpu,
    scene: &Scene,
    opts: &RenderOptions,
    load_time: Duration,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Rendered, RenderError> {
    opts.resolution.validate().map_err(RenderError::Settings)?;
    if opts.stop.threshold.is_nan() || opts.stop.threshold < 0.0 {
        return Err(RenderError::Settings(format!(
            "threshold {} must be >= 0",
            opts.stop.threshold
        )));
    }
    let mut timings = Timings {
        load: load_time.as_secs_f64(),
        ..Default::default()
    };
    let t = Instant::now();
    let mesh = Mesh::build(scene, &opts.mesh);
    timings.mesh = t.elapsed().as_secs_f64();
    log::info!(
        "{}: {} polygons, {} patches, {} elements",
        scene.name,
        scene.polygons.len(),
        mesh.patches.len(),
        mesh.elements.len()
    );

    let t = Instant::now();
    let mut source = GpuFormFactors::new(
        gpu,
        &mesh,
        opts.resolution,
        opts.raster_split,
        opts.layout,
        scene.extent(),
    )?;
    timings.setup = t.elapsed().as_secs_f64();

    let mut solver = Solver::new(&mesh);
    let mut ff = Vec::new();
    let mut shot_times = Vec::new();
    let (mut select, mut update) = (Duration::ZERO, Duration::ZERO);
    let solve_start = Instant::now();
    while !solver.done(&opts.stop) {
        let shot_start = Instant::now();
        let Some(shooter) = solver.select_shooter() else {
            break;
        };
        select += shot_start.elapsed();
        source.form_factors(shooter, &mut ff)?;
        let t = Instant::now();
        solver.shoot(shooter, &ff);
        update += t.elapsed();
        shot_times.push(shot_start.elapsed());
        progress(&Progress {
            shots: solver.shots(),
            unshot_fraction: solver.unshot_fraction(),
            elapsed: solve_start.elapsed(),
        });
    }
    timings.solve = solve_start.elapsed().as_secs_f64();
    timings.select_shooter = select.as_secs_f64();
    timings.update = update.as_secs_f64();
    timings.bounds = source.timings.bounds.as_secs_f64();
    timings.rects_per_shot = source.timings.rects as f64 / solver.shots().max(1) as f64;
    timings.rasterise = source.timings.rasterise.as_secs_f64();
    timings.read_back = source.timings.read_back.as_secs_f64();
    timings.sum_form_factors = source.timings.sum.as_secs_f64();
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

    let unshot_fraction = solver.unshot_fraction();
    let report = Report {
        scene: scene.name.clone(),
        settings: Settings {
            resolution: opts.resolution,
            threshold: opts.stop.threshold,
            max_shots: opts.stop.max_shots,
            mesh: opts.mesh,
            raster_split: opts.raster_split,
            image_size: [opts.width, height],
            shading: opts.shading,
            ambient: opts.ambient,
        },
        device: gpu.describe(),
        counts: Counts {
            polygons: scene.polygons.len(),
            patches: mesh.patches.len(),
            elements: mesh.elements.len(),
            cells: opts.resolution.cells(),
            ranks: 1,
        },
        shots: solver.shots(),
        unshot_fraction,
        converged: unshot_fraction <= opts.stop.threshold,
        emitted_power: solver.emitted_power(),
        timings,
        surfaces: report::surfaces(&mesh, &scene.nodes, solver.radiosity()),
        warnings: scene.warnings.clone(),
    };
    let radiosity = solver.radiosity().to_vec();
    drop(solver);
    drop(source);
    Ok(Rendered {
        mesh,
        radiosity,
        image,
        report,
    })
}
