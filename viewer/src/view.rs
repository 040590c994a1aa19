//! The 3-D view is drawn on its own thread, so the UI thread never waits on
//! the GPU: the UI sends the latest request and picks up finished images
//! when it paints. The thread keeps one `ViewRenderer` (pipelines, buffers
//! and target made once) for the whole session.

use eframe::egui::ColorImage;
use radiosity::gpu::{Gpu, ViewRenderer, ViewSettings};
use radiosity::lit_mesh::LitMesh;
use radiosity::scene::Camera;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// One image to draw.
pub struct Request<K> {
    /// What the image shows (returned with it).
    pub key: K,
    /// The mesh.
    pub mesh: Arc<LitMesh>,
    /// Display radiance per element.
    pub radiance: Arc<Vec<[f32; 3]>>,
    /// A patch to draw in magenta (the last shooter), if any.
    pub highlight: Option<u32>,
    /// From where.
    pub camera: Camera,
    /// Size and shading.
    pub settings: ViewSettings,
    /// Exposure adjustment in stops.
    pub ev: f32,
}

/// A finished image.
pub struct Finished<K> {
    /// The request's key.
    pub key: K,
    /// The tone-mapped image, or why there is none.
    pub image: Result<ColorImage, String>,
    /// How long drawing it took (GPU and read-back included).
    pub took: Duration,
}

/// The UI's handle on the view thread.
pub struct ViewWorker<K> {
    /// `None` once [`ViewWorker::stop`] has closed the channel.
    tx: Option<Sender<Request<K>>>,
    done: Arc<Mutex<Option<Finished<K>>>>,
    busy: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl<K: Send + 'static> ViewWorker<K> {
    /// Starts the thread; `wake` asks the UI to repaint when an image is ready.
    pub fn start(gpu: Gpu, wake: impl Fn() + Send + 'static) -> Result<Self, String> {
        let (tx, rx) = std::sync::mpsc::channel::<Request<K>>();
        let done = Arc::new(Mutex::new(None));
        let busy = Arc::new(AtomicBool::new(false));
        let (d, b) = (done.clone(), busy.clone());
        let thread = std::thread::Builder::new()
            .name("view".into())
            .spawn(move || run(gpu, rx, d, b, wake))
            .map_err(|e| format!("cannot start the view thread: {e}"))?;
        Ok(Self {
            tx: Some(tx),
            done,
            busy,
            thread: Some(thread),
        })
    }

    /// Closes the channel and waits, at most until `deadline`, for the
    /// thread to finish its drawing and leave the device: a thread still
    /// inside the driver when the process exits can crash it.
    pub fn stop(&mut self, deadline: Instant) {
        self.tx = None;
        if let Some(t) = self.thread.take() {
            join_by(t, deadline);
        }
    }

    /// Whether a request is being drawn (the UI then waits for it before
    /// sending the next, so requests never pile up).
    pub fn busy(&self) -> bool {
        self.busy.load(Ordering::Acquire)
    }

    /// Asks for an image.
    pub fn request(&self, r: Request<K>) {
        self.busy.store(true, Ordering::Release);
        if self.tx.as_ref().is_none_or(|tx| tx.send(r).is_err()) {
            self.busy.store(false, Ordering::Release);
        }
    }

    /// The image finished since the last call, if any.
    pub fn take(&self) -> Option<Finished<K>> {
        self.done.lock().ok()?.take()
    }
}

/// Joins `thread` if it finishes by `deadline`; otherwise leaves it (a
/// stuck driver must not keep the window from closing).
pub fn join_by(thread: std::thread::JoinHandle<()>, deadline: Instant) {
    while !thread.is_finished() {
        if Instant::now() >= deadline {
            log::warn!("a background thread did not finish in time; exiting without it");
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    // A panic there was already reported on its own thread.
    let _ = thread.join();
}

fn run<K>(
    gpu: Gpu,
    rx: Receiver<Request<K>>,
    done: Arc<Mutex<Option<Finished<K>>>>,
    busy: Arc<AtomicBool>,
    wake: impl Fn(),
) {
    let mut renderer = ViewRenderer::new(&gpu.device);
    while let Ok(mut r) = rx.recv() {
        // Only the newest request matters.
        while let Ok(newer) = rx.try_recv() {
            r = newer;
        }
        let start = Instant::now();
        let image = draw(&gpu, &mut renderer, &r);
        if let Ok(mut slot) = done.lock() {
            *slot = Some(Finished {
                key: r.key,
                image,
                took: start.elapsed(),
            });
        }
        busy.store(false, Ordering::Release);
        wake();
    }
}

fn draw<K>(gpu: &Gpu, renderer: &mut ViewRenderer, r: &Request<K>) -> Result<ColorImage, String> {
    let mut radiance: Vec<[f32; 3]> = r.radiance.as_ref().clone();
    if let Some(p) = r.highlight {
        if let Some(patch) = r.mesh.patches.get(p as usize) {
            for e in patch.elements.clone() {
                if let Some(x) = radiance.get_mut(e as usize) {
                    *x = [x[0].max(1.0) * 4.0, 0.0, x[2].max(1.0) * 4.0];
                }
            }
        }
    }
    let pixels = renderer
        .render(
            &gpu.device,
            &gpu.queue,
            &r.mesh,
            &radiance,
            &r.camera,
            &r.settings,
        )
        .map_err(|e| e.to_string())?;
    // Exposure follows the image itself, the shooter's magenta excluded.
    let hint: Vec<[f32; 3]> = pixels
        .iter()
        .filter(|p| !(p[1] == 0.0 && p[0] > 0.0 && p[2] > 0.0))
        .copied()
        .collect();
    let scale = radiosity::output::auto_exposure(&hint, r.ev);
    let bytes = radiosity::output::tone_map(&pixels, scale);
    Ok(ColorImage::from_rgb(
        [r.settings.width as usize, r.settings.height as usize],
        &bytes,
    ))
}
