//! The lab: what the project measures itself with, apart from the renderer
//! a user links. Benchmarks (`bench`), error against time beside a path
//! tracer (`accuracy`, `charted`, `receivers`, `regimes`), the performance
//! model and its fitting (`scaling`, `scaling_report`) and the fuzz
//! generator (`fuzz`). The `radiosity-lab` binary runs them; its tests check
//! the model against the committed calibration runs and run a fuzz corpus.

/// Draws one chart twice, as `STEM.svg` and `STEM.png` in `out`, at `size`:
/// `|root| body` is expanded once per backend (the drawing functions are
/// generic over it), and an error names the file.
macro_rules! svg_and_png {
    ($out:expr, $stem:expr, $size:expr, |$root:ident| $body:expr) => {{
        use plotters::prelude::IntoDrawingArea;
        let svg = $out.join(format!("{}.svg", $stem));
        {
            let $root = plotters::prelude::SVGBackend::new(&svg, $size).into_drawing_area();
            $body.map_err(|e| anyhow::anyhow!("{}: {e}", svg.display()))?;
        }
        let png = $out.join(format!("{}.png", $stem));
        {
            let $root = plotters::prelude::BitMapBackend::new(&png, $size).into_drawing_area();
            $body.map_err(|e| anyhow::anyhow!("{}: {e}", png.display()))?;
        }
    }};
}

pub mod accuracy;
pub mod bench;
pub mod charted;
pub mod fuzz;
pub mod image_time;
pub mod pooled;
pub mod receivers;
pub mod regimes;
pub mod scaling;
pub mod scaling_report;
