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
    /// Sizes of the problem.
    pub counts: Counts,
    /// Shots taken.
    pub shots: u64,
    /// Unshot power / emitted power at the end.
    pub unshot_fraction: f64,
    /// Whether the threshold was reached (rather than the shot limit).
    pub converged: bool,
    /// Total emitted power (sum over RGB), W.
    pub emitted_power: f64,
    /// Wall-clock seconds per phase.
    pub timings: Timings,
    /// Per glTF node: area and area-weighted mean radiosity.
    pub surfaces: Vec<Surface>,
    /// Non-fatal problems met on the way.
    pub warnings: Vec<String>,
}

/// The settings of a run.
#[derive(Clone, Debug, Serialize)]
pub struct Settings {
    /// Hemisphere resolution (R_phi x R_theta).
    pub resolution: Resolution,
    /// Stop at this unshot fraction.
    pub threshold: f64,
    /// Stop after this many shots.
    pub max_shots: u64,
    /// Subdivision settings.
    pub mesh: crate::mesh::MeshSettings,
    /// Rasterisation proxies per element edge.
    pub raster_split: u32,
    /// Image size.
    pub image_size: [u32; 2],
    /// Smooth or flat.
    pub shading: crate::gpu::Shading,
    /// Whether the ambient term was added to the image.
    pub ambient: bool,
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
    /// Mean rectangles drawn per shot.
    pub rects_per_shot: f64,
    /// Drawing hemispheres on the GPU and waiting for them (summed over shots).
    pub rasterise: f64,
    /// Reading item buffers back (summed over shots).
    pub read_back: f64,
    /// Summing delta form factors per element (summed over shots).
    pub sum_form_factors: f64,
    /// Distributing radiosity (summed over shots).
    pub update: f64,
    /// Rendering and writing the image.
    pub image: f64,
    /// Median milliseconds per shot.
    pub median_shot_ms: f64,
}

/// One glTF node's result.
#[derive(Clone, Debug, Serialize, serde::Deserialize, PartialEq)]
pub struct Surface {
    /// Node name.
    pub node: String,
    /// Area in m^2 (both sides of a double-sided surface).
    pub area: f64,
    /// Area-weighted mean radiosity, W/m^2 per channel.
    pub radiosity: [f64; 3],
}

/// Per-node areas and area-weighted mean radiosities.
pub fn surfaces(mesh: &Mesh, nodes: &[String], radiosity: &[[f64; 3]]) -> Vec<Surface> {
    let mut area = vec![0.0f64; nodes.len()];
    let mut sum = vec![[0.0f64; 3]; nodes.len()];
    for (e, b) in mesh.elements.iter().zip(radiosity) {
        let n = mesh.polygons[e.polygon as usize].node;
        area[n] += e.area;
        for c in 0..3 {
            sum[n][c] += b[c] * e.area;
        }
    }
    nodes
        .iter()
        .enumerate()
        .map(|(i, name)| Surface {
            node: name.clone(),
            area: area[i],
            radiosity: sum[i].map(|s| if area[i] > 0.0 { s / area[i] } else { 0.0 }),
        })
        .collect()
}
