//! The window: a 3-D view of the converging solution, the statistics and
//! controls, and the last shot's hemisphere.

use crate::solve::{self, Command, SaveRequest, Settings, Snapshot};
use crate::Args;
use eframe::egui::{self, Color32, ColorImage, TextureHandle, TextureOptions};
use glam::{EulerRot, Quat, Vec3};
use radiosity::gpu::{render_view, Gpu, Shading, ViewSettings};
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
    gpu: Gpu,
    tx: Sender<Command>,
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
        let (solver_gpu, solver_shared, ctx) = (gpu(), shared.clone(), cc.egui_ctx.clone());
        std::thread::Builder::new()
            .name("solve".into())
            .spawn(move || {
                solve::run(solver_gpu, scene, settings, rx, solver_shared, move || {
                    ctx.request_repaint()
                })
            })
            .map_err(|e| format!("cannot start the solve thread: {e}"))?;
        Ok(Self {
            rows: args.resolution.rows,
            threshold: args.threshold,
            patch_size: 0.0,
            args,
            gpu: gpu(),
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

    /// Redraws the 3-D view when anything it depends on changed.
    fn update_view(&mut self, ctx: &egui::Context, snap: &Snapshot, size: [u32; 2]) {
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
        if self.view.as_ref().is_some_and(|(_, k)| *k == key) || size[0] < 8 || size[1] < 8 {
            return;
        }
        let Some(mesh) = &snap.mesh else { return };
        if snap.radiance.len() != mesh.elements.len() {
            return;
        }
        let mut radiance = snap.radiance.clone();
        if let (true, Some(p)) = (self.highlight, snap.shooter) {
            for e in mesh.patches[p as usize].elements.clone() {
                radiance[e as usize] = [
                    radiance[e as usize][0].max(1.0) * 4.0,
                    0.0,
                    radiance[e as usize][2].max(1.0) * 4.0,
                ];
            }
        }
        let mut camera = self.orbit.camera();
        camera.aspect = Some(size[0] as f32 / size[1] as f32);
        let settings = ViewSettings {
            width: size[0],
            height: size[1],
            shading: self.shading,
            supersample: 1,
            wireframe: self.wireframe,
        };
        match render_view(
            &self.gpu.device,
            &self.gpu.queue,
            mesh,
            &radiance,
            &camera,
            &settings,
        ) {
            Ok(pixels) => {
                let scale =
                    radiosity::output::auto_exposure(&snap.radiance_pixels_hint(&pixels), self.ev);
                let bytes = radiosity::output::tone_map(&pixels, scale);
                let image = ColorImage::from_rgb([size[0] as usize, size[1] as usize], &bytes);
                match &mut self.view {
                    Some((tex, k)) => {
                        tex.set(image, TextureOptions::LINEAR);
                        *k = key;
                    }
                    None => {
                        self.view =
                            Some((ctx.load_texture("view", image, TextureOptions::LINEAR), key))
                    }
                }
            }
            Err(e) => self.status = format!("view: {e}"),
        }
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

    fn save(&mut self, snap: &Snapshot) {
        let stem = std::path::Path::new(&self.args.scene)
            .file_stem()
            .map_or_else(|| "scene".into(), |s| s.to_string_lossy().into_owned());
        let req = SaveRequest {
            camera: self.orbit.camera(),
            shading: self.shading,
            wireframe: self.wireframe,
            ev: self.ev,
            stem: std::path::PathBuf::from("out").join(format!("{stem}-{}", snap.shots)),
        };
        solve::send(&self.tx, Command::Save(req));
        self.status = "saving…".into();
    }

    fn side_panel(&mut self, ui: &mut egui::Ui, snap: &Snapshot) {
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
            ui.add(
                egui::DragValue::new(&mut self.patch_size)
                    .speed(0.005)
                    .range(0.0..=10.0)
                    .suffix(" m"),
            );
            ui.label(if self.patch_size > 0.0 {
                ""
            } else {
                "(scene / automatic)"
            });
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
        ui.separator();
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
        if ui.button("Save image and report").clicked() {
            self.save(snap);
        }
        ui.label(snap.saved.as_deref().unwrap_or(&self.status));
        ui.separator();
        ui.horizontal(|ui| {
            ui.heading("Convergence");
            ui.checkbox(&mut self.plot_time, "against time");
        });
        let points: Vec<[f64; 2]> = snap
            .history
            .iter()
            .filter(|h| h.2 > 0.0)
            .map(|h| [if self.plot_time { h.1 } else { h.0 as f64 }, h.2.log10()])
            .collect();
        egui_plot::Plot::new("convergence")
            .height(160.0)
            .x_axis_label(if self.plot_time { "seconds" } else { "shots" })
            .y_axis_label("log10 unshot fraction")
            .show(ui, |p| {
                p.line(egui_plot::Line::new(
                    "unshot",
                    egui_plot::PlotPoints::from(points),
                ))
            });
        ui.separator();
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
        });
        ctx.request_repaint();
    }
}

trait HintExt {
    fn radiance_pixels_hint(&self, pixels: &[[f32; 3]]) -> Vec<[f32; 3]>;
}

impl HintExt for Snapshot {
    /// Exposure follows the image itself, shooter highlight excluded.
    fn radiance_pixels_hint(&self, pixels: &[[f32; 3]]) -> Vec<[f32; 3]> {
        pixels
            .iter()
            .filter(|p| !(p[1] == 0.0 && p[0] > 0.0 && p[2] > 0.0))
            .copied()
            .collect()
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
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        let snap = self.snapshot();
        self.update_hemisphere(&ctx, &snap);
        egui::Panel::right("controls")
            .min_size(330.0)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.side_panel(ui, &snap));
            });
        egui::CentralPanel::default().show(ui, |ui| {
            let avail = ui.available_size();
            let ppp = ctx.pixels_per_point();
            let size = [(avail.x * ppp) as u32, (avail.y * ppp) as u32];
            self.update_view(&ctx, &snap, size);
            if let Some((tex, _)) = &self.view {
                let response = ui
                    .add(egui::Image::new((tex.id(), avail)).sense(egui::Sense::click_and_drag()));
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
    }

    fn on_exit(&mut self) {
        solve::send(&self.tx, Command::Quit);
    }
}
