//! The radiosity viewer: an egui window that watches a solve converge. The
//! binary is `radiosity-viewer`; the solve driver is a library module so its
//! logic (pause, step, resume, restart) is tested without a window.

pub mod app;
pub mod frames;
pub mod solve;
pub mod view;

use radiosity::hemisphere::Resolution;
use std::path::PathBuf;

/// Watch the radiosity of a scene converge, shot by shot.
#[derive(clap::Parser, Debug, Clone)]
#[command(version, about)]
pub struct Args {
    /// A .gltf/.glb file or a built-in scene (cornell, cubes-N, classroom-c1, ...).
    #[arg(default_value = "cornell")]
    pub scene: String,
    /// The glTF perspective camera to look from, by its name or its node's
    /// (the file's first by default); an unknown name is an error that
    /// lists the file's cameras.
    #[arg(long)]
    pub camera: Option<String>,
    /// A sun, a sky and photometric units, as the renderer takes them.
    #[command(flatten)]
    pub lights: radiosity::scene::light::LightArgs,
    /// Hemisphere resolution R_phi x R_theta.
    #[arg(long, default_value = "128x512")]
    pub resolution: Resolution,
    /// Stop when the unshot power is at most this fraction of the emitted power.
    #[arg(long, default_value_t = 1e-3)]
    pub threshold: f64,
    /// Pause after this many shots (with --screenshot: then save and exit).
    #[arg(long)]
    pub shots: Option<u64>,
    /// After --shots shots, save a PNG of the window here and exit.
    #[arg(long, requires = "shots")]
    pub screenshot: Option<PathBuf>,
    /// On exit, write frame-time statistics (JSON: median UI and
    /// frame-to-frame milliseconds, the last view image's drawing time) and
    /// the solve's shots, solve seconds and whether it converged, here.
    #[arg(long)]
    pub frame_stats: Option<PathBuf>,
    /// Close the window after this many seconds (for benchmarks).
    #[arg(long)]
    pub exit_after: Option<f64>,
    /// Close the window once the solve has converged (for benchmarks).
    #[arg(long)]
    pub exit_when_converged: bool,
    /// Repaint every frame, as fast as the machine allows, instead of when
    /// something changed (for the frame-rate benchmark: `--frame-stats`
    /// then measures the frame rate the viewer keeps up while it solves).
    #[arg(long)]
    pub continuous: bool,
    /// Compare the convergence plot with this reference (a report or a
    /// `radiosity-lab accuracy` reference JSON with `surfaces`): the plot then
    /// shows the area-weighted mean error per surface against time.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Window size in logical pixels, WxH.
    #[arg(long, default_value = "1280x760")]
    pub size: String,
}
