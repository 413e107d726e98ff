//! The inputs of the analysis commands, in one place: which file kinds a command accepts and
//! how each is read (CSV datasets of `docs/datasets.md`, or an MCAP log through the adapters of
//! `metrolog-analysis`), and where reports go. Every decision between a CSV and a log is made
//! here.

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use geometry::capball::{self, CapballRecord, CapballSetup};
use geometry::kinematics::Machine;
use positioning::positioning_data::PositioningData;

use super::progress::read_contents;

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
        return read_contents(path, "reading")
            .and_then(|log| metrolog_analysis::positioning::positioning_from_contents(&log, opts))
            .with_context(|| format!("reading the positioning run of {}", path.display()));
    }
    let (data, notes) = PositioningData::from_csv_str_noted(&read_text(path)?)
        .with_context(|| format!("reading {}", path.display()))?;
    // What a metrologist must know about the file's shape (renumbered cycles or targets,
    // passes against their direction): on stderr, so the results on stdout stay as they are.
    for n in notes {
        errln!("note: {}: {n}", path.display());
    }
    Ok(data)
}

/// Whether `path` holds CapBall data: a CSV whose header names `ex_um` (an MCAP log is
/// CapBall data only when asked for, e.g. `diagnose --capball`).
pub fn is_capball_csv(path: &Path) -> bool {
    if metrolog_analysis::is_mcap(path) {
        return false;
    }
    read_text(path)
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty())
                .map(|h| h.split(',').any(|c| c.trim() == "ex_um"))
        })
        .unwrap_or(false)
}

/// CapBall records and the machine they were read with.
pub struct CapballInput {
    pub records: Vec<CapballRecord>,
    pub machine: Machine,
    /// The kinematic convention the log's poses chose (a log read without a given machine).
    pub machine_name: Option<String>,
    /// Poses of a log left out, with their status.
    pub skipped: Vec<(u32, String)>,
    /// Where a damaged log is damaged (the records are those before the damage).
    pub damage: Option<String>,
}

impl CapballInput {
    /// The header line of a result built on a damaged log, when it is.
    pub fn damage_note(&self) -> Option<String> {
        self.damage.as_ref().map(|d| {
            format!(
                "BUILT ON PART OF THE RUN: the log is damaged: {d}; the CapBall result uses the \
                 poses before the damage only"
            )
        })
    }
}

/// The CapBall records of a CSV dataset or an MCAP log (the poses that hold the tool on the
/// ball, see [`metrolog_analysis::capball`]). With `machine` the records are read for it;
/// without, a log's poses choose the kinematic convention and a CSV is read for paper 001's
/// machine.
pub fn load_capball(path: &Path, machine: Option<Machine>) -> anyhow::Result<CapballInput> {
    if metrolog_analysis::is_mcap(path) {
        let context = || {
            format!(
                "reading the CapBall poses of {} (a CapBall input is a run's MCAP log or a CSV dataset)",
                path.display()
            )
        };
        let log = read_contents(path, "reading").with_context(context)?;
        let damage = log.damage();
        return Ok(match machine {
            Some(machine) => {
                let cb = metrolog_analysis::capball::capball_from_contents(&log, &machine)
                    .with_context(context)?;
                CapballInput {
                    records: cb.records,
                    machine,
                    machine_name: None,
                    skipped: cb.skipped,
                    damage,
                }
            }
            None => {
                let cb = metrolog_analysis::capball::capball_from_contents_auto(&log)
                    .with_context(context)?;
                CapballInput {
                    records: cb.records,
                    machine: cb.machine,
                    machine_name: Some(cb.machine_name),
                    skipped: cb.skipped,
                    damage,
                }
            }
        });
    }
    let records =
        capball::parse_dataset(&read_csv(path)?).with_context(|| format!("{}", path.display()))?;
    let machine = match machine {
        Some(m) => m,
        None => Machine::from_config(&CapballSetup::paper_machine_config())?,
    };
    Ok(CapballInput {
        records,
        machine,
        machine_name: None,
        skipped: Vec::new(),
        damage: None,
    })
}

/// The machine description of `--machine FILE` (TOML), or paper 001's WCAYFXZT machine.
pub fn load_machine(path: Option<&PathBuf>) -> anyhow::Result<Machine> {
    Ok(match path {
        Some(p) => {
            Machine::from_toml(&read_csv(p)?).with_context(|| format!("machine {}", p.display()))?
        }
        None => Machine::from_config(&CapballSetup::paper_machine_config())?,
    })
}

/// The largest text input a command reads (a CSV dataset, a budget, a description file),
/// bytes: far past any real one (a week of a thermal test at 1 Hz is tens of MB), and read whole
/// into memory.
pub const MAX_TEXT_INPUT_BYTES: u64 = 256 << 20;

/// The text of an input file: only a regular file (checked before it is opened: a FIFO would
/// block the command until a writer comes, a device could be read forever) of at most
/// [`MAX_TEXT_INPUT_BYTES`], in UTF-8. Each error names the file and what to fix.
pub fn read_text(p: &Path) -> anyhow::Result<String> {
    let meta = std::fs::metadata(p).with_context(|| format!("reading {}", p.display()))?;
    anyhow::ensure!(
        meta.is_file(),
        "{}: not a regular file (a directory, pipe or device); give the path of a file",
        p.display()
    );
    anyhow::ensure!(
        meta.len() <= MAX_TEXT_INPUT_BYTES,
        "{}: {} bytes is more than the {} MiB an input file may have",
        p.display(),
        meta.len(),
        MAX_TEXT_INPUT_BYTES >> 20
    );
    std::fs::read_to_string(p).with_context(|| format!("reading {} as UTF-8 text", p.display()))
}

/// The text of an input that must not be a log (a CSV dataset, a description file).
pub fn read_csv(p: &Path) -> anyhow::Result<String> {
    if metrolog_analysis::is_mcap(p) {
        anyhow::bail!(
            "{}: this input must be a CSV file (`identify capball` reads MCAP logs; the PSD \
             13-error identification needs the 51-point laser frame and a reference run as CSV — \
             a log's single PSD segment gives its straightness, printed by `metrolog demo`)",
            p.display()
        );
    }
    read_text(p)
}

/// The value of an option that takes `n` comma-separated numbers (`--layout`, `--ball-mm`);
/// `what` names the option in the error.
pub fn numbers_arg(s: &str, n: usize, what: &str) -> anyhow::Result<Vec<f64>> {
    let v: Result<Vec<f64>, _> = s.split(',').map(|x| x.trim().parse::<f64>()).collect();
    match v {
        Ok(v) if v.len() == n && v.iter().all(|x| x.is_finite()) => Ok(v),
        _ => anyhow::bail!("{what} `{s}`: expected {n} comma-separated numbers"),
    }
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

/// Writes a report to stdout; a closed pipe (`| head`) is not an error. A control character
/// other than a line break or a tab (an escape sequence from an input's text that a reader let
/// through) is printed as U+FFFD, never sent to the terminal.
pub fn print_out(text: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    let shown = terminal_safe(text);
    let mut out = std::io::stdout().lock();
    match out.write_all(shown.as_bytes()).and_then(|_| out.flush()) {
        // As the panic hook says it for `println!` (main.rs): the I/O error code.
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            Err(crate::exit::OutputWriteFailed(format!("cannot write the output: {e}")).into())
        }
        _ => Ok(()),
    }
}

/// One line on stderr, without control characters (see [`print_out`]); a stderr that cannot be
/// written is ignored, as `eprintln!` cannot report it either.
pub fn print_err(line: &str) {
    use std::io::Write as _;
    let _ = writeln!(std::io::stderr().lock(), "{}", terminal_safe(line));
}

/// `text` with every control character but `\n`, `\r` and `\t` replaced by U+FFFD.
pub fn terminal_safe(text: &str) -> std::borrow::Cow<'_, str> {
    let unsafe_char = |c: char| c.is_control() && !matches!(c, '\n' | '\r' | '\t');
    if !text.chars().any(unsafe_char) {
        return std::borrow::Cow::Borrowed(text);
    }
    text.chars()
        .map(|c| if unsafe_char(c) { '\u{fffd}' } else { c })
        .collect()
}

/// A thermal test (`time_s`, temperatures `_c`, optional `spindle_rpm` and displacements `_um`,
/// see [`thermal::ThermalDataset`]): a CSV file, or a run's log (its `/temperature` samples and
/// the pose values of its measuring pose, [`super::thermal::from_log`]).
pub fn load_thermal(path: &Path) -> anyhow::Result<thermal::ThermalDataset> {
    if metrolog_analysis::is_mcap(path) {
        return super::thermal::from_log::dataset_from_log(path);
    }
    let text = read_text(path)?;
    thermal::ThermalDataset::from_csv(&text).with_context(|| {
        format!(
            "{} is not a valid thermal test; fix the file at the place named",
            path.display()
        )
    })
}

/// Writes an output file whole or not at all: the text goes to a temporary file beside `path`,
/// which is synced and then renamed over `path`, so a reader never sees half a file and a
/// failed write leaves any earlier file as it was. A failure exits with the I/O error code.
pub fn write_output(path: &Path, text: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    let fail = |what: &str, e: std::io::Error| {
        crate::exit::OutputWriteFailed(format!("cannot write {}: {what}: {e}", path.display()))
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let mut tmp = tempfile::Builder::new()
        .prefix(".metrolog-")
        .suffix(".tmp")
        .tempfile_in(dir)
        .map_err(|e| fail("creating a temporary file in its directory", e))?;
    // tempfile creates the file 0600; an output is an ordinary file others may read.
    use std::os::unix::fs::PermissionsExt as _;
    tmp.write_all(text.as_bytes())
        .and_then(|_| {
            tmp.as_file()
                .set_permissions(std::fs::Permissions::from_mode(0o644))
        })
        .and_then(|_| tmp.as_file().sync_all())
        .map_err(|e| fail("writing", e))?;
    tmp.persist(path)
        .map_err(|e| fail("renaming the finished temporary file", e.error))?;
    Ok(())
}

/// A fresh, unused path beside `out` for an output whose writer creates the file itself (an
/// MCAP log): the file is removed when this is dropped (a failed command leaves nothing, and
/// nothing that makes the next run fail with "File exists"); [`finish_new_output`] renames it
/// to `out` once complete. `out` must not exist yet.
pub fn new_output_path(out: &Path) -> anyhow::Result<tempfile::TempPath> {
    anyhow::ensure!(
        !out.exists(),
        "{} exists; this command writes a new file, choose another name",
        out.display()
    );
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let tmp = tempfile::Builder::new()
        .prefix(".metrolog-")
        .suffix(".mcap.tmp")
        .make_in(dir, |_| Ok(()))
        .map_err(|e| {
            crate::exit::OutputWriteFailed(format!(
                "cannot write {}: reserving a temporary name in its directory: {e}",
                out.display()
            ))
        })?;
    Ok(tmp.into_temp_path())
}

/// Renames the complete temporary output to `out`, never over an existing file.
pub fn finish_new_output(tmp: tempfile::TempPath, out: &Path) -> anyhow::Result<()> {
    tmp.persist_noclobber(out).map_err(|e| {
        crate::exit::OutputWriteFailed(format!(
            "cannot write {}: renaming the finished temporary file: {}",
            out.display(),
            e.error
        ))
    })?;
    Ok(())
}

/// `--tolerance E=10`: the ISO 14253-1 decision of ISO 230-2 results against tolerances.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ToleranceArgs {
    /// Tolerance of an ISO 230-2 result, `SYMBOL=VALUE` with SYMBOL one of E, M, A, B, R and
    /// VALUE its upper limit in the deviation unit (µm; mdeg for a rotary axis). Repeat or
    /// comma-separate, e.g. `--tolerance E=10,R=4`. Each is decided by ISO 14253-1 (pass,
    /// fail or not decidable) with the result's expanded uncertainty U (k = 2).
    #[arg(long, value_delimiter = ',', value_name = "SYMBOL=VALUE", value_parser = parse_tolerance)]
    pub tolerance: Vec<(String, f64)>,
}

fn parse_tolerance(s: &str) -> Result<(String, f64), String> {
    let (k, v) = s
        .split_once('=')
        .ok_or_else(|| format!("`{s}`: expected SYMBOL=VALUE, e.g. E=10"))?;
    let k = k.trim().to_uppercase();
    if !["E", "M", "A", "B", "R"].contains(&k.as_str()) {
        return Err(format!(
            "`{k}`: a tolerance is for one of the ISO 230-2 results E, M, A, B, R"
        ));
    }
    let v: f64 = v
        .trim()
        .parse()
        .map_err(|_| format!("`{v}` is not a number"))?;
    if !(v.is_finite() && v > 0.0) {
        return Err(format!("tolerance {k} = {v}: must be a positive number"));
    }
    Ok((k, v))
}

/// `--assume KEY=VALUE`: contributors of the results' uncertainty the run did not record,
/// given by the operator (a certificate, a data sheet, a measurement made beside the run).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct AssumeArgs {
    /// A contributor of the ISO 230-2 results' uncertainty the run did not record, `KEY=VALUE`;
    /// repeat or comma-separate. Keys: device_um_per_m (expanded calibration uncertainty, k = 2),
    /// air_ppm, material_c, material_accuracy_k, alpha_um_per_m_k, alpha_accuracy_um_per_m_k,
    /// misalignment_mrad, dead_path_mm, air_range_k, pressure_range_kpa, e_ve_um. The report
    /// marks each as assumed (given with --assume); a value given replaces a recorded one.
    #[arg(long, value_delimiter = ',', value_name = "KEY=VALUE", value_parser = parse_assume)]
    pub assume: Vec<(String, f64)>,
}

impl AssumeArgs {
    /// Give every `--assume` value to the budget's setup (each was checked when parsed).
    pub fn apply(&self, setup: &mut positioning::iso230_uncertainty::Setup) {
        for (k, v) in &self.assume {
            // Checked by parse_assume: give() cannot refuse it here.
            let _ = setup.give(k, *v, "given with --assume");
        }
    }
}

fn parse_assume(s: &str) -> Result<(String, f64), String> {
    let (k, v) = s
        .split_once('=')
        .ok_or_else(|| format!("`{s}`: expected KEY=VALUE, e.g. device_um_per_m=0.5"))?;
    let k = k.trim().to_lowercase();
    let v: f64 = v
        .trim()
        .parse()
        .map_err(|_| format!("{k} = `{v}`: not a number"))?;
    positioning::iso230_uncertainty::check_given(&k, v)?;
    Ok((k, v))
}

pub use uncertainty::mc::{MAX_NDIG, MAX_TRIALS};

/// `--trials N`: a whole number from 1 to [`MAX_TRIALS`] (2⁶⁴ − 1 trials aborted on an
/// allocation of exabytes).
pub fn trials_arg(s: &str) -> Result<usize, String> {
    match s.trim().parse::<usize>() {
        Ok(n) if (1..=MAX_TRIALS).contains(&n) => Ok(n),
        _ => Err(format!(
            "`{s}`: the number of trials is a whole number from 1 to {MAX_TRIALS} (each trial's \
             outputs are kept in memory)"
        )),
    }
}

/// `--ndig N`: a whole number from 1 to [`MAX_NDIG`].
pub fn ndig_arg(s: &str) -> Result<u32, String> {
    match s.trim().parse::<u32>() {
        Ok(n) if (1..=MAX_NDIG).contains(&n) => Ok(n),
        _ => Err(format!(
            "`{s}`: the significant digits of the tolerance are a whole number from 1 to \
             {MAX_NDIG} (each digit needs about 100 times the trials)"
        )),
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn reports_reach_the_terminal_without_escape_sequences() {
        let plain = "a\tb\r\nc µm\n";
        assert!(matches!(
            super::terminal_safe(plain),
            std::borrow::Cow::Borrowed(_)
        ));
        assert_eq!(
            super::terminal_safe("x\u{1b}[2Jy\u{7}"),
            "x\u{fffd}[2Jy\u{fffd}"
        );
    }
}
