//! GPU plumbing (wgpu): getting a device, the hemisphere rasteriser, and the
//! camera-view renderer. Nothing here knows about radiosity updates or MPI.
//!
//! Following wgpu's examples, acquiring a device ([`Gpu::new`]) is separate from
//! doing work with `&Device, &Queue`, so tests can share one device.

mod hemisphere;
mod target;
mod view;

pub use hemisphere::{HemisphereRasterizer, Peers, RasterStats};
pub use view::{render_view, view_depth_range, Shading, Shown, ViewRenderer, ViewSettings};

use std::time::Duration;

/// The longest any single wait on the device may take before we give up
/// (a stalled software driver must fail loudly, not hang).
pub const DEVICE_TIMEOUT: Duration = Duration::from_secs(120);

/// Why GPU work failed.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No adapter could be found.
    #[error("no Vulkan adapter found ({0}); install a Vulkan driver: on Debian 'apt-get install mesa-vulkan-drivers libvulkan1' (lavapipe runs on the CPU)")]
    NoAdapter(String),
    /// The adapter refused to create a device.
    #[error("cannot create a device on '{adapter}': {message}")]
    Device {
        /// Adapter name.
        adapter: String,
        /// Why.
        message: String,
    },
    /// The device did not finish in time.
    #[error("the GPU did not finish within {0:?} (driver stalled?)")]
    Timeout(Duration),
    /// Any other failure while waiting on or reading from the device.
    #[error("GPU failure: {0}")]
    Failed(String),
    /// A setting the GPU code cannot use.
    #[error("invalid setting: {0}")]
    Setting(String),
    /// The scene is too big for this device.
    #[error("scene too large for the device: {0}")]
    TooLarge(String),
}

/// A device and its queue, with a description of the adapter.
pub struct Gpu {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// The adapter it runs on.
    pub info: wgpu::AdapterInfo,
}

/// Keeps Mesa's device-selection layer out of a headless process. The
/// layer is implicit: it asks the window system (Wayland, then X) which GPU
/// drives the display, and without one it prints "error: XDG_RUNTIME_DIR is
/// invalid or not set" on every run, though nothing is wrong. A renderer
/// with no window has no display to match, so unless the user chose a
/// device through the layer (`MESA_VK_DEVICE_SELECT`) or set
/// `NODEVICE_SELECT` themselves, it is switched off by the loader's own
/// switch. Call it first thing in `main`, before any thread starts (it sets
/// the process environment).
pub fn leave_out_device_select_layer() {
    let chosen = ["NODEVICE_SELECT", "MESA_VK_DEVICE_SELECT"]
        .iter()
        .any(|v| std::env::var_os(v).is_some());
    if !chosen {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
}

/// The backends the renderer and the viewer open: Vulkan only (its float
/// render targets need it, and a missing driver must be an error rather
/// than a fall-back to GL), unless `WGPU_BACKEND` says otherwise.
pub fn backends() -> wgpu::Backends {
    wgpu::Backends::from_env().unwrap_or(wgpu::Backends::VULKAN)
}

impl Gpu {
    /// Opens the first suitable adapter. Vulkan only unless `WGPU_BACKEND` says otherwise.
    pub fn new() -> Result<Gpu, GpuError> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = backends();
        let instance = wgpu::Instance::new(desc);
        let options = wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        };
        let adapter = pollster::block_on(instance.request_adapter(&options))
            .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        Self::from_adapter(&adapter)
    }

    /// Opens a device on a given adapter with the limits this renderer needs.
    pub fn from_adapter(adapter: &wgpu::Adapter) -> Result<Gpu, GpuError> {
        let info = adapter.get_info();
        let desc = wgpu::DeviceDescriptor {
            label: Some("radiosity"),
            required_features: wgpu::Features::empty(),
            required_limits: adapter.limits(),
            ..Default::default()
        };
        let (device, queue) =
            pollster::block_on(adapter.request_device(&desc)).map_err(|e| GpuError::Device {
                adapter: info.name.clone(),
                message: e.to_string(),
            })?;
        Ok(Gpu {
            device,
            queue,
            info,
        })
    }

    /// Whether the adapter is a CPU rasteriser (lavapipe, llvmpipe, WARP).
    pub fn is_cpu(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// "name (backend, driver)" for reports and logs.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {} {})",
            self.info.name, self.info.backend, self.info.driver, self.info.driver_info
        )
    }
}

/// Maps the first `bytes` of `buffer` for reading, waiting at most
/// [`DEVICE_TIMEOUT`] for `submission`.
pub(crate) fn map_read(
    device: &wgpu::Device,
    buffer: &wgpu::Buffer,
    submission: wgpu::SubmissionIndex,
    bytes: std::ops::RangeTo<u64>,
) -> Result<(), GpuError> {
    let (tx, rx) = std::sync::mpsc::channel();
    buffer
        .slice(bytes)
        .map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
    device
        .poll(wgpu::PollType::Wait {
            submission_index: Some(submission),
            timeout: Some(DEVICE_TIMEOUT),
        })
        .map_err(|e| match e {
            wgpu::PollError::Timeout => GpuError::Timeout(DEVICE_TIMEOUT),
            other => GpuError::Failed(other.to_string()),
        })?;
    match rx.recv_timeout(DEVICE_TIMEOUT) {
        Ok(Ok(())) => Ok(()),
        Ok(Err(e)) => Err(GpuError::Failed(e.to_string())),
        Err(_) => Err(GpuError::Timeout(DEVICE_TIMEOUT)),
    }
}
