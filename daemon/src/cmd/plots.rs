//! The charts of the analysis commands. Plots are a build feature (`--features plot`, on in CI
//! and in `cargo install --features plot`): the acquisition service that a shop-floor PC runs
//! does not link the plotting stack (`docs/design.md`). Without the feature, `--plot` says how
//! to get a build that draws.

#[cfg(feature = "plot")]
pub use metrolog_analysis::plot::diagnosis::draw_diagnosis;
#[cfg(feature = "plot")]
pub use metrolog_analysis::plot::positioning::draw_positioning;
#[cfg(feature = "plot")]
pub use metrolog_analysis::plot::uncertainty::write as draw_uncertainty;

#[cfg(not(feature = "plot"))]
pub use without::{draw_diagnosis, draw_positioning, draw_uncertainty};

#[cfg(not(feature = "plot"))]
mod without {
    use std::path::Path;

    use diagnose::axis::Diagnosis;
    use metrolog_analysis::positioning_report::PositioningAnalysis;
    use positioning::positioning_data::PositioningData;
    use uncertainty::{GumResult, McResult};

    fn no_plots(path: &Path) -> anyhow::Error {
        anyhow::anyhow!(
            "cannot draw {}: this metrolog was built without plots (the service build); \
             build it with `cargo build --release --features plot` to draw charts",
            path.display()
        )
    }

    pub fn draw_positioning(
        path: &Path,
        _: &PositioningData,
        _: &PositioningAnalysis,
        _: usize,
    ) -> anyhow::Result<()> {
        Err(no_plots(path))
    }

    pub fn draw_diagnosis(path: &Path, _: &PositioningData, _: &Diagnosis) -> anyhow::Result<()> {
        Err(no_plots(path))
    }

    pub fn draw_uncertainty(
        path: &Path,
        _: &str,
        _: &[Option<String>],
        _: &McResult,
        _: Option<&GumResult>,
    ) -> anyhow::Result<()> {
        Err(no_plots(path))
    }
}
