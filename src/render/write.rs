//! The one write path for a render's outputs, used by the binary and the
//! viewer alike: the image (EXR and PNG preview), then a check that the
//! solution is finite, then the bake, then the JSON report. Each file is
//! written atomically; a non-finite solution writes no report.

use crate::bake::Baked;
use crate::mesh::Mesh;
use crate::output::{self, OutputError};
use crate::report::Report;
use crate::scene::Scene;
use std::path::{Path, PathBuf};

/// Where a render's outputs go.
#[derive(Clone, Debug)]
pub struct OutputPaths {
    /// The EXR (its PNG preview goes beside it); `None`: no image.
    pub image: Option<PathBuf>,
    /// PNG preview exposure in stops over automatic.
    pub exposure: f32,
    /// The baked glTF, if asked for.
    pub bake: Option<PathBuf>,
    /// The JSON report.
    pub report: PathBuf,
}

impl OutputPaths {
    /// Checks that every output can be written (see
    /// [`output::check_writable`]), the image's PNG preview included, when
    /// `image` says there will be one.
    pub fn check(&self, image: bool) -> Result<(), OutputError> {
        let exr = self.image.as_ref().filter(|_| image);
        let png = exr.map(|p| p.with_extension("png"));
        exr.into_iter()
            .chain(&png)
            .chain(&self.bake)
            .chain(std::iter::once(&self.report))
            .try_for_each(|p| output::check_writable(p))
    }
}

/// What was written.
#[derive(Clone, Debug)]
pub struct Written {
    /// The EXR and PNG paths.
    pub image: Option<(PathBuf, PathBuf)>,
    /// The bake's summary (also in the report).
    pub bake: Option<Baked>,
    /// The report's path.
    pub report: PathBuf,
}

impl Written {
    /// One line per file written, as the binary prints them.
    pub fn lines(&self) -> Vec<String> {
        let mut out = Vec::new();
        if let Some((exr, png)) = &self.image {
            out.push(format!("wrote {} and {}", exr.display(), png.display()));
        }
        if let Some(b) = &self.bake {
            out.push(format!(
                "wrote {} ({} nodes, {} triangles, COLOR_0 = min(1, B/pi x {:.4}))",
                b.path, b.nodes, b.triangles, b.scale
            ));
        }
        out.push(format!("wrote {}", self.report.display()));
        out
    }
}

/// Why the outputs could not all be written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// A file could not be written.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// The solution is not finite (a bug): the report is not written.
    #[error("{scene}: the solution has a non-finite number in {what}; no report written")]
    NonFinite {
        /// The scene.
        scene: String,
        /// Where.
        what: String,
    },
}

/// A camera image: width, height and linear radiance pixels, top row first.
pub type Image<'a> = (u32, u32, &'a [[f32; 3]]);

/// Writes `image` (if any, and if `paths` has a place for it), checks the
/// solution, bakes `radiosity` over `mesh` when asked, and writes `report`
/// (with the bake's summary added).
pub fn write_outputs(
    paths: &OutputPaths,
    scene: &Scene,
    mesh: &Mesh,
    radiosity: &[[f64; 3]],
    image: Option<Image>,
    report: &mut Report,
) -> Result<Written, WriteError> {
    let image = match (image, &paths.image) {
        (Some((w, h, pixels)), Some(exr)) => {
            let png = output::write_image(exr, w, h, pixels, paths.exposure)?;
            Some((exr.clone(), png))
        }
        _ => None,
    };
    if let Some(what) = report.non_finite() {
        return Err(WriteError::NonFinite {
            scene: scene.name.clone(),
            what,
        });
    }
    let bake = match &paths.bake {
        Some(path) => Some(crate::bake::write(path, scene, mesh, radiosity)?),
        None => None,
    };
    report.bake = bake.clone();
    output::write_json(&paths.report, report)?;
    Ok(Written {
        image,
        bake,
        report: paths.report.clone(),
    })
}

/// The stem outputs of a scene are named after: a file's stem, or a
/// built-in scene's name (`render` when there is none).
pub fn output_stem(scene: &str) -> String {
    Path::new(scene)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "render".into())
}
