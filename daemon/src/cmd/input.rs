//! The inputs of the analysis commands, in one place: which file kinds a command accepts and
//! how each is read (CSV datasets of `docs/datasets.md`, or an MCAP log through the adapters of
//! `metrolog-analysis`), and where reports go.

use std::path::Path;

use anyhow::Context as _;
use positioning::positioning_data::PositioningData;

/// Reads a positioning run from a CSV dataset or an MCAP log (see
/// [`metrolog_analysis::positioning`] for how the run is found in a log).
pub fn load_positioning(path: &Path) -> anyhow::Result<PositioningData> {
    load_positioning_with(path, &metrolog_analysis::PositioningOptions::default())
}

/// [`load_positioning`] with the options of the MCAP adapter (ignored for CSV).
pub fn load_positioning_with(
    path: &Path,
    opts: &metrolog_analysis::PositioningOptions,
) -> anyhow::Result<PositioningData> {
    if metrolog_analysis::is_mcap(path) {
        return super::progress::read_contents(path, "reading")
            .and_then(|log| metrolog_analysis::positioning::positioning_from_contents(&log, opts))
            .with_context(|| format!("reading the positioning run of {}", path.display()));
    }
    PositioningData::from_csv_path(path).with_context(|| format!("reading {}", path.display()))
}

/// `--units`: the units of a dataset that does not declare them.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct UnitArgs {
    /// Units of the targets and the deviations, comma-separated (e.g. `deg,mdeg` for a rotary
    /// axis), for a file without `# target_unit:` / `# deviation_unit:` lines [default: the
    /// file's, else mm,µm].
    #[arg(long, value_name = "TARGET,DEVIATION")]
    pub units: Option<String>,
}

impl UnitArgs {
    /// Writes the units into the dataset's metadata. A unit the file declares differently is
    /// an error: the file or the option is wrong, and a report must not guess which.
    pub fn apply(&self, data: &mut PositioningData) -> anyhow::Result<()> {
        let Some(spec) = &self.units else {
            return Ok(());
        };
        let parts: Vec<&str> = spec.split(',').map(str::trim).collect();
        let [target, deviation] = parts[..] else {
            anyhow::bail!(
                "--units {spec}: give two units, the targets' and the deviations', e.g. \
                 --units deg,mdeg"
            );
        };
        for (key, unit) in [("target_unit", target), ("deviation_unit", deviation)] {
            anyhow::ensure!(
                positioning::units::is_plain_unit(unit),
                "--units {spec}: `{unit}` is not a unit name (1 to 12 letters, digits or the \
                 signs µ ° ' \" / · ^ -)"
            );
            match data.metadata.get(key) {
                Some(declared) if declared != unit => anyhow::bail!(
                    "--units {spec}: the file declares `{key}: {declared}`; correct the file \
                     or drop --units"
                ),
                _ => {
                    data.metadata.insert(key.into(), unit.into());
                }
            }
        }
        Ok(())
    }
}

/// Writes a report to stdout; a closed pipe (`| head`) is not an error.
pub fn print_out(text: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|_| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e.into()),
        _ => Ok(()),
    }
}
