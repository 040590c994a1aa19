//! The window: a 3-D view of the converging solution, the statistics and
//! controls, and the last shot's hemisphere.

use crate::frames::{BenchStats, FrameTimes};
use crate::solve::{self, Command, SaveRequest, Settings, Snapshot};
use crate::view::{Request, ViewWorker};
use crate::Args;
use eframe::egui::{self, Color32, ColorImage, TextureHandle, TextureOptions};
use glam::{EulerRot, Quat, Vec3};
use radiosity::gpu::{Gpu, Shading, ViewSettings};
use radiosity::hemisphere::{Resolution, TileLayout, BLOCKED, EMPTY};
use radiosity::render::RenderOptions;
use radiosity::scene::{Camera, Scene};
use std::sync::mpsc::Sender;
use std::sync::{Arc, Mutex};

/// An orbit around a target point.
#[derive(Clone, Copy, PartialEq)]
struct Orbit {
    target: Vec3,
    distance: f32,
    yaw: f32,
    pitch: f32,
    yfov: f32,
}

impl Orbit {
    fn from_camera(c: &Camera, centre: Vec3) -> Self {
        let (yaw, pitch, _) = c.rotation.to_euler(EulerRot::YXZ);
        let forward = c.rotation * -Vec3::Z;
        let distance = (centre - c.position).dot(forward).max(1e-3);
        Self {
            target: c.position + forward * distance,
            distance,
            yaw,
            pitch,
            yfov: c.yfov,
        }
    }

    fn camera(&self) -> Camera {
        let rotation = Quat::from_euler(EulerRot::YXZ, self.yaw, self.pitch, 0.0);
        let position = self.target - rotation * -Vec3::Z * self.distance;
        Camera {
            position,
            rotation,
            yfov: self.yfov,
            aspect: None,
            znear: self.distance * 1e-3,
        }
    }
}

/// Least time between view redraws that only new radiosities ask for.
const VIEW_REFRESH: std::time::Duration = std::time::Duration::from_millis(250);

/// The longest a background change (new radiosities, a new view image)
/// waits for a frame.
const BACKGROUND_FRAME: std::time::Duration = std::time::Duration::from_millis(200);

/// What the last drawn view was drawn from, to redraw only on change.
#[derive(Clone, Copy, PartialEq)]
struct ViewKey {
    version: u64,
    orbit: [f32; 5],
    size: [u32; 2],
    ev: f32,
    shading: Shading,
    highlight: bool,
    wireframe: bool,
}

/// The viewer's state.
pub struct Viewer {
    args: Args,
    tx: Sender<Command>,
    /// The solve's thread, joined on exit (see [`crate::view::join_by`]).
    solve_thread: Option<std::thread::JoinHandle<()>>,
    shared: Arc<Mutex<Snapshot>>,
    home: Orbit,
    orbit: Orbit,
    ev: f32,
    shading: Shading,
    highlight: bool,
    wireframe: bool,
    by_rank: bool,
    ranks: u32,
    plot_time: bool,
    rows: u32,
    threshold: f64,
    /// Patch size for restarts, metres (0: the scene's extras or the automatic rule).
    patch_size: f32,
    view: Option<(TextureHandle, ViewKey)>,
    /// Per-node radiosities to measure the convergence against (`--reference`).
    reference: Option<Vec<radiosity::report::Surface>>,
    /// Draws the 3-D view off the UI thread.
    worker: ViewWorker<ViewKey>,
    /// When the window opened.
    started: std::time::Instant,
    /// When the last view image was asked for.
    last_request: std::time::Instant,
    /// How long the last view image took to draw (on the view thread).
    view_ms: f64,
    /// Recent frame times (UI work, and frame to frame), for the status line.
    frames: FrameTimes,
    hemi: Option<(TextureHandle, u64, bool, u32)>,
    status: String,
    screenshot_requested: bool,
    result: Arc<Mutex<Result<(), String>>>,
}

impl Viewer {
    /// Starts the solve on eframe's own wgpu device.
    pub fn new(
        cc: &eframe::CreationContext<'_>,
        args: Args,
        scene: Scene,
        result: Arc<Mutex<Result<(), String>>>,
    ) -> Result<Self, String> {
        let rs = cc.wgpu_render_state.as_ref().ok_or(
            "eframe started without wgpu (install mesa-vulkan-drivers for a Vulkan adapter)",
        )?;
        let gpu = || Gpu {
            device: rs.device.clone(),
            queue: rs.queue.clone(),
            info: rs.adapter.get_info(),
        };
        let (lo, hi) = scene.bounds();
        let camera = scene.camera.unwrap_or_else(|| scene.default_camera());
        let home = Orbit::from_camera(&camera, 0.5 * (lo + hi));
        let shared = Arc::new(Mutex::new(Snapshot::default()));
        let (tx, rx) = std::sync::mpsc::channel();
        let mut options = RenderOptions {
            resolution: args.resolution,
            ..RenderOptions::default()
        };
        options.stop.threshold = args.threshold;
        let settings = Settings {
            options,
            pause_at: args.shots,
        };
        let reference = match &args.reference {
            Some(path) => Some(read_reference(path)?),
            None => None,
        };
        let view_ctx = cc.egui_ctx.clone();
        // Background news (a new view image, a new solution) repaints at
        // most every BACKGROUND_FRAME: a frame costs lavapipe tens of ms of
        // both cores, which the solve needs. Input still repaints at once.
        let worker = ViewWorker::start(gpu(), move || {
            view_ctx.request_repaint_after(BACKGROUND_FRAME)
        })?;
        let (solver_gpu, solver_shared, ctx) = (gpu(), shared.clone(), cc.egui_ctx.clone());
        let solve_thread = std::thread::Builder::new()
            .name("solve".into())
            .spawn(move || {
                solve::run(solver_gpu, scene, settings, rx, solver_shared, move || {
                    ctx.request_repaint_after(BACKGROUND_FRAME)
                })
            })
            .map_err(|e| format!("cannot start the solve thread: {e}"))?;
        Ok(Self {
            rows: args.resolution.rows,
            threshold: args.threshold,
            patch_size: 0.0,
            args,
            tx,
            shared,
            home,
            orbit: home,
            ev: 0.0,
            shading: Shading::Smooth,
            highlight: true,
            wireframe: false,
            by_rank: false,
            ranks: 4,
            plot_time: false,
            view: None,
            reference,
            worker,
            solve_thread: Some(solve_thread),
            view_ms: 0.0,
            last_request: std::time::Instant::now(),
            started: std::time::Instant::now(),
            frames: FrameTimes::default(),
            hemi: None,
            status: String::new(),
            screenshot_requested: false,
            result,
        })
    }

    fn snapshot(&self) -> Snapshot {
        self.shared.lock().map(|s| s.clone()).unwrap_or_default()
    }

    fn restart(&mut self) {
        let mut options = RenderOptions {
            resolution: Resolution {
                rows: self.rows,
                cols: 4 * self.rows,
            },
            ..RenderOptions::default()
        };
        options.stop.threshold = self.threshold;
        options.mesh.patch_size = (self.patch_size > 0.0).then_some(self.patch_size);
        solve::send(
            &self.tx,
            Command::Restart(Settings {
                options,
                pause_at: None,
            }),
        );
    }

    /// Shows the newest finished view image, and asks the view thread for
    /// a new one when anything it depends on changed. Never waits on the GPU.
    fn update_view(&mut self, ctx: &egui::Context, snap: &Snapshot, size: [u32; 2]) {
        if let Some(done) = self.worker.take() {
            self.view_ms = done.took.as_secs_f64() * 1e3;
            match done.image {
                Ok(image) => match &mut self.view {
                    Some((tex, k)) => {
                        tex.set(image, TextureOptions::LINEAR);
                        *k = done.key;
                    }
                    None => {
                        self.view = Some((
                            ctx.load_texture("view", image, TextureOptions::LINEAR),
                            done.key,
                        ))
                    }
                },
                Err(e) => self.status = format!("view: {e}"),
            }
        }
        let o = &self.orbit;
        let key = ViewKey {
            version: snap.version,
            orbit: [
                o.distance,
                o.yaw,
                o.pitch,
                o.target.x + o.target.y,
                o.target.z,
            ],
            size,
            ev: self.ev,
            shading: self.shading,
            highlight: self.highlight,
            wireframe: self.wireframe,
        };
        let shown = self.view.as_ref().is_some_and(|(_, k)| *k == key);
        if shown || self.worker.busy() || size[0] < 8 || size[1] < 8 {
            return;
        }
        // While it solves, new radiosities alone redraw the view at most
        // VIEW_REFRESH apart: each image costs the view thread tens of ms of
        // a shared core, which the frames and the solve need more. A camera
        // or setting change redraws at once.
        let only_newer = self.view.as_ref().is_some_and(|(_, k)| {
            ViewKey {
                version: key.version,
                ..*k
            } == key
        });
        if only_newer && self.last_request.elapsed() < VIEW_REFRESH {
            ctx.request_repaint_after(VIEW_REFRESH - self.last_request.elapsed());
            return;
        }
        self.last_request = std::time::Instant::now();
        let Some(mesh) = &snap.mesh else { return };
        if snap.radiance.len() != mesh.elements.len() {
            return;
        }
        let mut camera = self.orbit.camera();
        camera.aspect = Some(size[0] as f32 / size[1] as f32);
        self.worker.request(Request {
            key,
            mesh: mesh.clone(),
            radiance: snap.radiance.clone(),
            highlight: if self.highlight { snap.shooter } else { None },
            camera,
            settings: ViewSettings {
                width: size[0],
                height: size[1],
                shading: self.shading,
                supersample: 1,
                wireframe: self.wireframe,
            },
            ev: self.ev,
        });
    }

    /// Redraws the hemisphere panel from the last item buffer.
    fn update_hemisphere(&mut self, ctx: &egui::Context, snap: &Snapshot) {
        let key = (snap.version, self.by_rank, self.ranks);
        if self
            .hemi
            .as_ref()
            .is_some_and(|(_, v, b, r)| (*v, *b, *r) == key)
        {
            return;
        }
        let (rows, cols) = snap.resolution;
        if snap.items.len() != (rows * cols) as usize || rows == 0 {
            return;
        }
        let (px, py) = radiosity::parallel::rank_grid(self.ranks as usize);
        let layout = TileLayout {
            tile_w: 1,
            tile_h: 1,
            px,
            py,
        };
        let pixels: Vec<Color32> = snap
            .items
            .iter()
            .enumerate()
            .map(|(i, &id)| {
                let base = match id {
                    EMPTY => Color32::BLACK,
                    BLOCKED => Color32::from_gray(60),
                    id => hashed(id),
                };
                if self.by_rank {
                    let (x, y) =
                        layout.owner((i / cols as usize) as u32, (i % cols as usize) as u32);
                    let rank = hashed(y * px + x + 7919);
                    if id == EMPTY {
                        Color32::from_rgb(rank.r() / 3, rank.g() / 3, rank.b() / 3)
                    } else {
                        rank
                    }
                } else {
                    base
                }
            })
            .collect();
        let image = ColorImage {
            size: [cols as usize, rows as usize],
            pixels,
            source_size: egui::vec2(cols as f32, rows as f32),
        };
        match &mut self.hemi {
            Some((tex, v, b, r)) => {
                tex.set(image, TextureOptions::NEAREST);
                (*v, *b, *r) = key;
            }
            None => {
                self.hemi = Some((
                    ctx.load_texture("hemisphere", image, TextureOptions::NEAREST),
                    key.0,
                    key.1,
                    key.2,
                ))
            }
        }
    }

    fn save(&mut self, snap: &Snapshot, bake: bool) {
        let stem = std::path::Path::new(&self.args.scene)
            .file_stem()
            .map_or_else(|| "scene".into(), |s| s.to_string_lossy().into_owned());
        let req = SaveRequest {
            camera: self.orbit.camera(),
            shading: self.shading,
            wireframe: self.wireframe,
            ev: self.ev,
            stem: std::path::PathBuf::from("out").join(format!("{stem}-{}", snap.shots)),
            bake,
        };
        solve::send(&self.tx, Command::Save(req));
        self.status = "saving…".into();
    }

    fn side_panel(&mut self, ui: &mut egui::Ui, snap: &Snapshot) {
        self.solve_status(ui, snap);
        self.solve_controls(ui);
        ui.separator();
        self.view_controls(ui, snap);
        ui.separator();
        self.convergence_plot(ui, snap);
        ui.separator();
        self.hemisphere_panel(ui, snap);
    }

    /// Where the solve stands.
    fn solve_status(&self, ui: &mut egui::Ui, snap: &Snapshot) {
        ui.heading("Solve");
        if let Some(e) = &snap.error {
            ui.colored_label(Color32::RED, e);
        }
        ui.label(format!("shots: {}", snap.shots));
        ui.label(format!("unshot fraction: {:.3e}", snap.unshot_fraction));
        ui.label(format!("elapsed: {:.2} s", snap.elapsed.as_secs_f64()));
        let rate = if snap.elapsed.as_secs_f64() > 0.0 {
            snap.shots as f64 / snap.elapsed.as_secs_f64()
        } else {
            0.0
        };
        ui.label(format!("shots per second: {rate:.0}"));
        ui.label(if snap.converged {
            "converged"
        } else if snap.paused {
            "paused"
        } else {
            "shooting"
        });
    }

    /// Pause, step, resume, and the settings a restart takes.
    fn solve_controls(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            if ui.button("Pause").clicked() {
                solve::send(&self.tx, Command::Pause);
            }
            if ui.button("Step").clicked() {
                solve::send(&self.tx, Command::Step);
            }
            if ui.button("Resume").clicked() {
                solve::send(&self.tx, Command::Resume);
            }
        });
        ui.horizontal(|ui| {
            ui.label("R_phi");
            egui::ComboBox::from_id_salt("rows")
                .selected_text(format!("{} x {}", self.rows, 4 * self.rows))
                .show_ui(ui, |ui| {
                    for r in [64, 128, 160, 192, 256] {
                        ui.selectable_value(&mut self.rows, r, format!("{r} x {}", 4 * r));
                    }
                });
        });
        ui.horizontal(|ui| {
            ui.label("patch size");
            // 0 is the scene's own subdivision or the automatic rule.
            ui.add(
                egui::DragValue::new(&mut self.patch_size)
                    .speed(0.005)
                    .range(0.0..=10.0)
                    .custom_formatter(|v, _| {
                        if v > 0.0 {
                            format!("{v:.3} m")
                        } else {
                            "automatic".into()
                        }
                    })
                    .custom_parser(|t| {
                        let t = t.trim().trim_end_matches('m').trim();
                        if t.eq_ignore_ascii_case("automatic") || t.eq_ignore_ascii_case("auto") {
                            Some(0.0)
                        } else {
                            t.parse().ok()
                        }
                    }),
            );
        });
        ui.horizontal(|ui| {
            ui.label("stop at");
            ui.add(
                egui::DragValue::new(&mut self.threshold)
                    .speed(1e-4)
                    .range(1e-6..=1.0),
            );
            if ui.button("Restart").clicked() {
                self.restart();
            }
        });
    }

    /// Exposure, shading, camera, saving and frame times.
    fn view_controls(&mut self, ui: &mut egui::Ui, snap: &Snapshot) {
        ui.heading("View");
        ui.add(egui::Slider::new(&mut self.ev, -6.0..=6.0).text("exposure (EV)"));
        ui.horizontal(|ui| {
            ui.radio_value(&mut self.shading, Shading::Smooth, "smooth");
            ui.radio_value(&mut self.shading, Shading::Flat, "flat (elements)");
        });
        ui.checkbox(&mut self.highlight, "highlight the shooter");
        ui.checkbox(&mut self.wireframe, "element wireframe");
        if ui.button("Reset camera").clicked() {
            self.orbit = self.home;
        }
        ui.horizontal(|ui| {
            if ui.button("Save image and report").clicked() {
                self.save(snap, false);
            }
            if ui.button("… and bake glTF").clicked() {
                self.save(snap, true);
            }
        });
        ui.label(snap.saved.as_deref().unwrap_or(&self.status));
        let f = self.frames.summary(self.view_ms);
        ui.label(format!(
            "frame: {:.1} ms CPU ({:.1} ms UI), {:.1} ms apart (medians of {}); view image {:.1} ms off-thread",
            f.cpu_ms_median, f.ui_ms_median, f.interval_ms_median, f.frames, f.view_ms
        ));
    }

    /// The unshot fraction, or the error against `--reference`, over shots or time.
    fn convergence_plot(&mut self, ui: &mut egui::Ui, snap: &Snapshot) {
        ui.horizontal(|ui| {
            ui.heading("Convergence");
            ui.checkbox(&mut self.plot_time, "against time");
        });
        let x = |shots: u64, seconds: f64| {
            if self.plot_time {
                seconds
            } else {
                shots as f64
            }
        };
        let mut plot = egui_plot::Plot::new("convergence")
            .height(160.0)
            .x_axis_label(if self.plot_time { "seconds" } else { "shots" });
        if let Some(reference) = &self.reference {
            // The trace's per-node radiosities against the reference: the
            // same error `radiosity-lab accuracy` charts.
            // The refinement passes' points count their own shots: against
            // shots only the final solve's are drawn, against time all.
            let (mean, worst): (Vec<[f64; 2]>, Vec<[f64; 2]>) = snap
                .trace
                .iter()
                .filter(|p| self.plot_time || p.pass.is_none())
                .filter_map(|p| {
                    let (m, w) = radiosity::report::relative_error(&p.surfaces, reference);
                    (m > 0.0 && w > 0.0).then(|| {
                        let at = x(p.shots, p.seconds);
                        ([at, m.log10()], [at, w.log10()])
                    })
                })
                .unzip();
            plot = plot.y_axis_label("log10 relative error");
            plot.show(ui, |p| {
                p.line(egui_plot::Line::new(
                    "mean per surface",
                    egui_plot::PlotPoints::from(mean),
                ));
                p.line(egui_plot::Line::new(
                    "worst surface",
                    egui_plot::PlotPoints::from(worst),
                ));
                p.hline(egui_plot::HLine::new("1 %", -2.0));
            });
        } else {
            let points: Vec<[f64; 2]> = snap
                .history
                .iter()
                .filter(|h| h.2 > 0.0)
                .map(|h| [x(h.0, h.1), h.2.log10()])
                .collect();
            plot = plot.y_axis_label("log10 unshot fraction");
            plot.show(ui, |p| {
                p.line(egui_plot::Line::new(
                    "unshot",
                    egui_plot::PlotPoints::from(points),
                ))
            });
        }
    }

    /// The last shot's item buffer.
    fn hemisphere_panel(&mut self, ui: &mut egui::Ui, snap: &Snapshot) {
        ui.horizontal(|ui| {
            ui.heading("Hemisphere");
            ui.checkbox(&mut self.by_rank, "by rank");
            if self.by_rank {
                ui.add(
                    egui::DragValue::new(&mut self.ranks)
                        .range(1..=64)
                        .suffix(" ranks"),
                );
            }
        });
        if let Some((tex, ..)) = &self.hemi {
            let w = ui.available_width();
            let (rows, cols) = snap.resolution;
            ui.image((
                tex.id(),
                egui::vec2(w, w * rows as f32 / cols.max(1) as f32),
            ));
        }
    }

    /// A run nobody watches (`--screenshot`, `--exit-after`,
    /// `--exit-when-converged`) that meets an error ends with it, instead of
    /// waiting for a restart that will not come.
    fn end_unattended_run_on_error(&mut self, ctx: &egui::Context, snap: &Snapshot) {
        let unattended = self.args.screenshot.is_some()
            || self.args.exit_after.is_some()
            || self.args.exit_when_converged;
        let Some(e) = snap.error.as_ref().filter(|_| unattended) else {
            return;
        };
        if let Ok(mut r) = self.result.lock() {
            *r = Err(e.clone());
        }
        ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        ctx.request_repaint();
    }

    fn take_screenshot_when_ready(&mut self, ctx: &egui::Context, snap: &Snapshot) {
        let (Some(path), Some(n)) = (self.args.screenshot.clone(), self.args.shots) else {
            return;
        };
        let ready = (snap.shots >= n || snap.converged)
            && snap.paused
            && self
                .view
                .as_ref()
                .is_some_and(|(_, k)| k.version == snap.version);
        if !ready || self.screenshot_requested {
            return;
        }
        self.screenshot_requested = true;
        let (result, ctx2) = (self.result.clone(), ctx.clone());
        ctx.request_screenshot(move |image| {
            let bytes: Vec<u8> = image
                .pixels
                .iter()
                .flat_map(|c| [c.r(), c.g(), c.b()])
                .collect();
            let outcome =
                image::RgbImage::from_raw(image.size[0] as u32, image.size[1] as u32, bytes)
                    .ok_or_else(|| "screenshot has the wrong size".to_string())
                    .and_then(|img| {
                        let mut buf = std::io::Cursor::new(Vec::new());
                        img.write_to(&mut buf, image::ImageFormat::Png)
                            .map_err(|e| e.to_string())?;
                        radiosity::output::write_atomic(&path, &buf.into_inner())
                            .map_err(|e| e.to_string())
                    });
            if let Ok(mut r) = result.lock() {
                *r = outcome;
            }
            ctx2.send_viewport_cmd(egui::ViewportCommand::Close);
            // The command takes effect at the next frame: ask for it now.
            ctx2.request_repaint();
        });
        ctx.request_repaint();
    }
}

/// A stable, bright colour per id.
fn hashed(id: u32) -> Color32 {
    let h = id.wrapping_mul(2_654_435_761);
    Color32::from_rgb(
        64 + (h >> 24) as u8 % 192,
        64 + (h >> 16) as u8 % 192,
        64 + (h >> 8) as u8 % 192,
    )
}

impl eframe::App for Viewer {
    fn clear_color(&self, visuals: &egui::Visuals) -> [f32; 4] {
        visuals.panel_fill.to_normalized_gamma_f32()
    }

    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        let frame_start = std::time::Instant::now();
        // The previous frame's whole CPU time (UI, tessellation, painting).
        if let Some(cpu) = frame.info().cpu_usage {
            self.frames.record_cpu(cpu as f64 * 1e3);
        }
        let ctx = ui.ctx().clone();
        let snap = self.snapshot();
        self.update_hemisphere(&ctx, &snap);
        // No panel paints a background: the frame's clear colour is the
        // panels' fill, and the view image covers the central panel. On a
        // software rasteriser every pixel painted twice costs (1280 x 760,
        // paused: 53 ms a frame with both fills, 36 ms without the central one).
        let side = egui::Frame::side_top_panel(ui.style()).fill(Color32::TRANSPARENT);
        egui::Panel::right("controls")
            .min_size(330.0)
            .frame(side)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.side_panel(ui, &snap));
            });
        egui::CentralPanel::default()
            .frame(egui::Frame::NONE)
            .show(ui, |ui| {
                let avail = ui.available_size();
                let ppp = ctx.pixels_per_point();
                // While it solves, the view is drawn at half the window's pixels
                // (a quarter of the work for the view thread, which shares the
                // cores with the solve and the window); full size once it stops.
                let scale = if snap.paused || snap.converged {
                    1.0
                } else {
                    0.5
                };
                let size = [
                    (avail.x * ppp * scale) as u32,
                    (avail.y * ppp * scale) as u32,
                ];
                self.update_view(&ctx, &snap, size);
                if let Some((tex, _)) = &self.view {
                    let response = ui.add(
                        egui::Image::new((tex.id(), avail)).sense(egui::Sense::click_and_drag()),
                    );
                    let d = response.drag_delta();
                    if response.dragged_by(egui::PointerButton::Primary) {
                        self.orbit.yaw -= d.x * 0.01;
                        self.orbit.pitch = (self.orbit.pitch - d.y * 0.01).clamp(-1.5, 1.5);
                    } else if response.dragged_by(egui::PointerButton::Secondary) {
                        let cam = self.orbit.camera();
                        let k = self.orbit.distance * 0.002;
                        self.orbit.target += (cam.rotation * Vec3::X) * (-d.x * k)
                            + (cam.rotation * Vec3::Y) * (d.y * k);
                    }
                    if response.hovered() {
                        let scroll = ui.input(|i| i.smooth_scroll_delta.y);
                        self.orbit.distance *= (-scroll * 0.002).exp();
                    }
                } else {
                    ui.centered_and_justified(|ui| ui.label("preparing the scene…"));
                }
            });
        self.take_screenshot_when_ready(&ctx, &snap);
        self.end_unattended_run_on_error(&ctx, &snap);
        self.frames.record(frame_start);
        if self.args.continuous {
            // Benchmark: paint continuously, so frame-to-frame time is the
            // frame rate the viewer can keep up while it solves.
            ctx.request_repaint();
        }
        let timed_out = self
            .args
            .exit_after
            .is_some_and(|s| self.started.elapsed().as_secs_f64() >= s);
        if let Some(s) = self.args.exit_after {
            // An idle window paints no frames: wake it when it is time to go.
            let left = s - self.started.elapsed().as_secs_f64();
            ctx.request_repaint_after(std::time::Duration::from_secs_f64(left.max(0.0)));
        }
        if timed_out || (self.args.exit_when_converged && snap.converged) {
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
    }

    fn on_exit(&mut self) {
        if let Some(path) = &self.args.frame_stats {
            let snap = self.snapshot();
            let stats = BenchStats {
                frames: self.frames.summary(self.view_ms),
                shots: snap.shots,
                solve_seconds: snap.elapsed.as_secs_f64(),
                converged: snap.converged,
            };
            if let Err(e) = radiosity::output::write_json(path, &stats) {
                eprintln!("cannot write {}: {e}", path.display());
            }
        }
        solve::send(&self.tx, Command::Quit);
        // Both threads use the device: let them leave it before the
        // process exits (a detached one inside lavapipe at exit crashed
        // the viewer about once in fifteen test runs). A shot or a view
        // takes well under this, even on Sponza.
        let deadline = std::time::Instant::now() + EXIT_WAIT;
        self.worker.stop(deadline);
        if let Some(t) = self.solve_thread.take() {
            crate::view::join_by(t, deadline);
        }
    }
}

/// How long closing the window waits for the background threads.
const EXIT_WAIT: std::time::Duration = std::time::Duration::from_secs(10);

/// The `surfaces` of a report or of a `radiosity-lab accuracy` reference.
fn read_reference(path: &std::path::Path) -> Result<Vec<radiosity::report::Surface>, String> {
    #[derive(serde::Deserialize)]
    struct WithSurfaces {
        surfaces: Vec<radiosity::report::Surface>,
    }
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read the reference {}: {e}", path.display()))?;
    serde_json::from_str::<WithSurfaces>(&text)
        .map(|r| r.surfaces)
        .map_err(|e| format!("{}: not a report or reference ({e})", path.display()))
}
