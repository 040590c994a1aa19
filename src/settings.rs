//! The choices a render is told about that the report records: plain data,
//! low in the module graph so that the report, the checkpoint and the render
//! driver can all name them without importing one another.

/// Default shadow rays per emitter per image sample (`--shadow-rays`).
pub const DEFAULT_SHADOW_RAYS: u32 = 1;

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

impl FormFactorMethod {
    /// The name the command line and the checkpoint fingerprint use.
    pub fn name(self) -> &'static str {
        match self {
            Self::Hemisphere => "Hemisphere",
            Self::Hybrid => "Hybrid",
        }
    }
}

/// What a display of a solution adds for the light not yet shot, the
/// ambient term (`--ambient`): in the report's radiosities, the trace, the
/// image and the viewer. The solver never sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum AmbientTerm {
    /// Nothing: the radiosity shot so far.
    Off,
    /// Cohen et al. 1988: the unshot power spread evenly over the scene's
    /// area, reflected by its mean reflectance.
    Even,
    /// The unshot power carried bounce by bounce along the scene's geometry
    /// (`ambient::Transport`: ray-sampled shares between patches).
    #[default]
    Carried,
}

impl AmbientTerm {
    /// Whether a display adds anything.
    pub fn is_on(self) -> bool {
        self != Self::Off
    }
}

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

impl Projection {
    /// The name the checkpoint fingerprint uses.
    pub fn name(self) -> &'static str {
        match self {
            Self::Exact => "Exact",
            Self::Tessellated => "Tessellated",
        }
    }
}

/// Where the exact projection's hemisphere cells are drawn
/// (`--rasteriser`): by the wgpu device, or by the renderer on the CPU
/// (`gpu::HemisphereRasterizer::set_software`: the same test per cell).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Rasteriser {
    /// On the CPU where the adapter is itself a CPU rasteriser (lavapipe,
    /// which draws a shot's cells several times slower: docs/notebook/shot-phases.md), on the device otherwise.
    #[default]
    Auto,
    /// Always by the wgpu device.
    Device,
    /// Always on the CPU (the tessellated projection still draws on the
    /// device: it needs fixed-function rasterisation).
    Cpu,
}

impl Rasteriser {
    /// Where hemispheres are drawn on an adapter that is (`adapter_is_cpu`)
    /// or is not a CPU rasteriser: `Device` or `Cpu`, never `Auto`.
    pub fn resolve(self, adapter_is_cpu: bool) -> Self {
        match self {
            Self::Auto if adapter_is_cpu => Self::Cpu,
            Self::Auto => Self::Device,
            other => other,
        }
    }
}

/// Whether the ranks of a run deal the polygons' bounds between them
/// (`--deal-bounds`; the same bits either way, only the time changes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DealBounds {
    /// On every run of ranks whose scene has at least
    /// [`DEAL_BOUNDS_POLYGONS`] polygons.
    #[default]
    Auto,
    /// Over any number of ranks above one.
    On,
    /// Never: every rank bounds the polygons that may show in its tiles.
    Off,
}

/// The fewest polygons of a scene whose bounds `--deal-bounds auto` deals
/// (on any number of ranks above one: measured on cubes-b1 and
/// classroom-c3, docs/notebook/ranks.md "Ranks", since the pieces travel as (proxy, cell
/// rectangle), 20 bytes instead of the whole 152-byte rectangle, a shot is
/// 1.5-5 % faster dealt at 2 ranks and a rank's CPU 7-9 % less at 4; with
/// the 152-byte pieces 2 ranks had not gained).
/// A smaller scene's bounds cost next to nothing (the 64-cube room's 396
/// polygons: 0.08 ms a shot on one rank), and its few polygons, some of
/// them walls of hundreds of elements, deal unevenly (the Cornell box on 2
/// ranks: one rank bounded 83 % of the rectangles).
pub const DEAL_BOUNDS_POLYGONS: usize = 1024;

impl DealBounds {
    /// Whether `ranks` ranks of a run deal the bounds of a scene of
    /// `polygons` polygons.
    pub fn deals(self, ranks: usize, polygons: usize) -> bool {
        match self {
            Self::Auto => ranks > 1 && polygons >= DEAL_BOUNDS_POLYGONS,
            Self::On => ranks > 1,
            Self::Off => false,
        }
    }
}

/// Pieces per quad polygon edge the hemisphere rasteriser draws by default
/// (chosen by `radiosity-lab bench`; see docs/notebook/shot-speed.md "Performance").
pub const DEFAULT_RASTER_PIECES: u32 = 1;

/// The memory each rank aims to stay within by default, bytes (`--memory`):
/// issue 19's bound for a 100 000-polygon scene on one rank.
pub const DEFAULT_MEMORY_BUDGET: u64 = 2_000_000_000;

/// Shooters below this fraction of the emitted power draw the coarse
/// hemisphere (`--coarse-below`; docs/method/form-factors.md "Coarse hemispheres for weak shooters").
pub const DEFAULT_COARSE_BELOW: f64 = 3e-3;

/// The transport tier's threshold where it is on by default (meshes of more
/// than `ambient::PATCH_GROUPS` patches; see
/// `render::RenderOptions::transport_below_for`): on Sponza its error curve
/// follows the hemispheres' (docs/bench/transport-below.md), where 1e-3
/// stays 0.5 points above, and on the 18 referenced scenes, which it was
/// tried on as a flag, every final figure stays within 1 % mean and 3 %
/// worst.
pub const AUTO_TRANSPORT_BELOW: f64 = 1e-4;

/// Default tolerance of the tessellated projection, in cells.
pub const DEFAULT_TESSELLATION_TOLERANCE: f32 = 0.1;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_deals_the_bounds_of_big_scenes_on_every_run_of_ranks() {
        let big = DEAL_BOUNDS_POLYGONS;
        assert!(
            !DealBounds::Auto.deals(1, 100_000),
            "one rank has no one to deal with"
        );
        assert!(DealBounds::Auto.deals(2, big) && DealBounds::Auto.deals(64, big));
        assert!(
            !DealBounds::Auto.deals(2, big - 1),
            "a small scene's bounds stay undealt"
        );
        assert!(DealBounds::On.deals(2, 37) && !DealBounds::On.deals(1, 37));
        assert!(!DealBounds::Off.deals(8, 100_000));
    }
}
