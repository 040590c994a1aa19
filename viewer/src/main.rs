//! `radiosity-viewer`: watch a radiosity solve converge.

use anyhow::{Context, Result};
use clap::Parser;
use radiosity_viewer::{app, Args};

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn"))
        .format_timestamp(None)
        .init();
    if let Err(e) = run(Args::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run(args: Args) -> Result<()> {
    // A bad scene is reported before any window opens.
    let mut scene = radiosity::scene::open(&args.scene)?;
    if let Some(name) = &args.camera {
        scene.use_camera(name)?;
    }
    args.lights.apply(&mut scene)?;
    scene.check_lit()?;
    let (w, h) = args
        .size
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<f32>().ok()?, h.parse::<f32>().ok()?)))
        .context("--size must be WxH, e.g. 1280x760")?;
    // The renderer's backends (Vulkan only by default).
    let mut setup = eframe::egui_wgpu::WgpuSetupCreateNew::without_display_handle();
    setup.instance_descriptor.backends = radiosity::gpu::backends();
    // The adapter's own limits, as the renderer asks (`Gpu::new`): wgpu's
    // defaults cap a buffer at 256 MB, and Sponza's rasterisation proxies
    // need 377 MB.
    setup.device_descriptor = std::sync::Arc::new(|adapter| eframe::wgpu::DeviceDescriptor {
        label: Some("radiosity-viewer device"),
        required_limits: adapter.limits(),
        ..Default::default()
    });
    let mut wgpu_options = eframe::egui_wgpu::WgpuConfiguration {
        wgpu_setup: eframe::egui_wgpu::WgpuSetup::CreateNew(setup),
        ..Default::default()
    };
    if args.continuous {
        // The frame benchmark measures what a frame costs, not the display's
        // refresh: no waiting for vertical sync.
        wgpu_options.surface.present_mode = eframe::wgpu::PresentMode::AutoNoVsync;
    }
    let options = eframe::NativeOptions {
        renderer: eframe::Renderer::Wgpu,
        wgpu_options,
        viewport: eframe::egui::ViewportBuilder::default()
            .with_inner_size([w, h])
            .with_title(format!("radiosity — {}", args.scene)),
        ..Default::default()
    };
    let result = std::sync::Arc::new(std::sync::Mutex::new(Ok(())));
    let app_result = result.clone();
    eframe::run_native(
        "radiosity-viewer",
        options,
        Box::new(move |cc| {
            let app = app::Viewer::new(cc, args, scene, app_result).map_err(|e| -> Box<dyn std::error::Error + Send + Sync> { e.into() })?;
            Ok(Box::new(app))
        }),
    )
    .map_err(|e| anyhow::anyhow!("cannot open the window: {e} (no display? run under Xvfb: xvfb-run -a radiosity-viewer ...; no Vulkan adapter? apt-get install mesa-vulkan-drivers)"))?;
    let outcome = result
        .lock()
        .map_err(|_| anyhow::anyhow!("state lock poisoned"))?;
    outcome.clone().map_err(|e| anyhow::anyhow!(e))
}
