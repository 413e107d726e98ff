//! A positioning measurement of one linear axis (`docs/datasets.md`): the readings of an
//! interferometer at programmed targets, over repeated bidirectional cycles, with their times
//! and the environment. Read from the CSV dataset format, or built by an adapter (MCAP log) or
//! by [`simulate`] from an [`AxisModel`].

use std::collections::BTreeMap;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::axis_model::{AxisModel, Direction};

/// One interferometer reading at a target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Reading {
    /// Cycle number, 1..n.
    pub cycle: usize,
    /// Direction of approach.
    pub direction: Direction,
    /// Target number, 1..m.
    pub index: usize,
    /// Programmed target, mm.
    pub target_mm: f64,
    /// Measured minus target, µm (after environmental compensation).
    pub deviation_um: f64,
    /// Seconds since the start of the run (row order when the dataset had no times).
    pub time_s: f64,
    /// Air temperature at the reading, °C.
    pub air_c: Option<f64>,
    /// Material (axis) temperature at the reading, °C.
    pub material_c: Option<f64>,
}

/// A whole positioning run.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PositioningData {
    /// Axis name (metadata `axis`), if known.
    pub axis: Option<String>,
    /// Expansion coefficient of the axis, µm/(m·K) (metadata `alpha_um_per_m_k`).
    pub alpha_um_per_m_k: Option<f64>,
    /// `false` when the deviations were not normalised to 20 °C (`material_compensation: off`).
    pub material_compensation: bool,
    /// `true` when the readings carry real times; `false` when row order stands in for time
    /// (then `time_s` counts readings, one per second).
    pub has_times: bool,
    /// All `# key: value` metadata as read.
    pub metadata: BTreeMap<String, String>,
    /// Readings in the order they were taken.
    pub readings: Vec<Reading>,
}

/// Why a dataset could not be read.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// cannot read the dataset (the cause follows)
    #[error("cannot read the dataset")]
    Io(#[from] std::io::Error),
    /// the dataset has no header row (expected e.g. `cycle,direction,index,target_mm,deviation_um`)
    #[error(
        "the dataset has no header row (expected e.g. `cycle,direction,index,target_mm,deviation_um`)"
    )]
    NoHeader,
    /// the header lacks the required column `{0}`
    #[error(
        "the header lacks the required column `{0}` (required: cycle, direction, index, target_mm, deviation_um)"
    )]
    MissingColumn(&'static str),
    /// line {line}: {message}
    #[error("line {line}: {message}")]
    BadRow { line: u64, message: String },
    /// bad metadata `{key}: {value}`: {message}
    #[error("bad metadata `{key}: {value}`: {message}")]
    BadMetadata {
        key: String,
        value: String,
        message: String,
    },
    /// the dataset holds no readings
    #[error("the dataset holds no readings")]
    Empty,
    /// the dataset is inconsistent: {0}
    #[error("the dataset is inconsistent: {0}")]
    Inconsistent(String),
    /// the dataset holds more than {0} readings
    #[error(
        "the dataset holds more than {0} readings; a positioning run has a few hundred to a few \
         thousand (split the file by run)"
    )]
    TooLarge(usize),
}

/// The most readings a dataset may hold: far beyond any positioning run (ISO 230-2: 5 to 50
/// targets, 5 bidirectional cycles), and what the analyses handle in well under 1 GB.
pub const MAX_READINGS: usize = 100_000;

/// The metadata key of a dataset read from a damaged log (set by the log adapter): where the
/// damage is and how much was read. Results on it are built on part of the run, and readings
/// missing after the damage are the log's loss, not beam interruptions.
pub const LOG_DAMAGE_KEY: &str = "log_damage";

/// The physical range of a numeric column (its unit in its name): a number outside it is a
/// damaged file or a unit mistake, refused where it is read rather than let into a result.
fn column_range(name: &str) -> Option<(f64, f64, &'static str)> {
    match name {
        "target_mm" => Some((-1e6, 1e6, "a target (±1 km, or ±10⁶ of the target unit)")),
        "deviation_um" => Some((
            -1e6,
            1e6,
            "a deviation (±1 m, or ±10⁶ of the deviation unit)",
        )),
        "time_s" => Some((-1e9, 1e9, "a time since the start (±30 years)")),
        "air_c" => Some((-60.0, 100.0, "an air temperature (°C)")),
        "material_c" => Some((-60.0, 200.0, "a material temperature (°C)")),
        _ => None,
    }
}

/// The largest expansion coefficient accepted, µm/(m·K) (polymers reach about 200).
const MAX_ALPHA_UM_PER_M_K: f64 = 1000.0;

impl PositioningData {
    /// Units of the target and deviation columns: metadata `target_unit` and
    /// `deviation_unit`, mm and µm when absent.
    pub fn units(&self) -> crate::units::Units {
        let d = crate::units::Units::default();
        let get = |k: &str, def: String| {
            self.metadata
                .get(k)
                .filter(|v| !v.is_empty())
                .cloned()
                .unwrap_or(def)
        };
        crate::units::Units {
            target: get("target_unit", d.target.clone()),
            deviation: get("deviation_unit", d.deviation.clone()),
        }
    }

    /// Reads a dataset from a CSV file.
    pub fn from_csv_path(path: &std::path::Path) -> Result<Self, DatasetError> {
        let text = std::fs::read_to_string(path)?;
        Self::from_csv_str(&text)
    }

    /// Reads a dataset from a CSV file, with the notes on its shape ([`Self::from_csv_str_noted`]).
    pub fn from_csv_path_noted(
        path: &std::path::Path,
    ) -> Result<(Self, Vec<String>), DatasetError> {
        let text = std::fs::read_to_string(path)?;
        Self::from_csv_str_noted(&text)
    }

    /// Reads a dataset from CSV text, with what a metrologist should know about its shape:
    /// cycle or target numbers that do not count 1, 2, 3, … (renumbered in their order, said
    /// how), and passes that visit their targets against their direction (swapped labels?).
    pub fn from_csv_str_noted(text: &str) -> Result<(Self, Vec<String>), DatasetError> {
        let mut data = Self::from_csv_str_raw(text)?;
        let mut notes = control_character_notes(text);
        notes.extend(renumber(&mut data.readings));
        data.validate()?;
        notes.extend(data.pass_direction_notes());
        Ok((data, notes))
    }

    /// Reads a dataset from CSV text (`docs/datasets.md`); the notes on its shape are dropped
    /// (see [`Self::from_csv_str_noted`]), the renumbering is not.
    pub fn from_csv_str(text: &str) -> Result<Self, DatasetError> {
        Self::from_csv_str_noted(text).map(|(d, _)| d)
    }

    fn from_csv_str_raw(text: &str) -> Result<Self, DatasetError> {
        let mut metadata = BTreeMap::new();
        for line in text.lines() {
            let t = line.trim_start();
            if let Some((k, v)) = t.strip_prefix('#').and_then(|rest| rest.split_once(':')) {
                let k = k.trim();
                if !k.is_empty() && !k.contains(' ') {
                    metadata.insert(printable(k), printable(v.trim()));
                }
            }
        }
        let mut rdr = csv::ReaderBuilder::new()
            .comment(Some(b'#'))
            .trim(csv::Trim::All)
            .flexible(true)
            .has_headers(true)
            .from_reader(text.as_bytes());
        let headers = rdr.headers().map_err(|_| DatasetError::NoHeader)?.clone();
        if headers.is_empty() || headers.iter().all(|h| h.is_empty()) {
            return Err(DatasetError::NoHeader);
        }
        check_unique_columns(&headers)?;
        let col = |name: &str| headers.iter().position(|h| h.eq_ignore_ascii_case(name));
        let need = |name: &'static str| col(name).ok_or(DatasetError::MissingColumn(name));
        let c_cycle = need("cycle")?;
        let c_dir = need("direction")?;
        let c_index = need("index")?;
        let c_target = need("target_mm")?;
        let c_dev = need("deviation_um")?;
        let c_time = col("time_s");
        let c_air = col("air_c");
        let c_mat = col("material_c");

        let mut readings = Vec::new();
        for (row_no, rec) in rdr.records().enumerate() {
            if readings.len() >= MAX_READINGS {
                return Err(DatasetError::TooLarge(MAX_READINGS));
            }
            // Line numbers from byte offsets: the csv crate's own count skips comment lines.
            let line_of = |byte: u64| {
                let bytes = text.as_bytes();
                let mut b = (byte as usize).min(bytes.len());
                // A record's position is where the reader started, before skipped comments.
                while b < bytes.len()
                    && (bytes[b] == b'#' || bytes[b] == b'\n' || bytes[b] == b'\r')
                {
                    if bytes[b] == b'#' {
                        b += bytes[b..]
                            .iter()
                            .position(|c| *c == b'\n')
                            .unwrap_or(bytes.len() - b);
                    }
                    b += 1;
                }
                let b = b.min(bytes.len());
                bytes[..b].iter().filter(|c| **c == b'\n').count() as u64 + 1
            };
            let rec = rec.map_err(|e| DatasetError::BadRow {
                line: e.position().map(|p| line_of(p.byte())).unwrap_or(0),
                message: e.to_string(),
            })?;
            // Counted only for an error: counting for every row would be quadratic.
            let byte = rec.position().map(|p| p.byte());
            let bad = |message: String| DatasetError::BadRow {
                line: byte.map(line_of).unwrap_or(0),
                message,
            };
            let field = |c: usize, name: &str| -> Result<&str, DatasetError> {
                rec.get(c).ok_or_else(|| {
                    bad(format!(
                        "missing field `{name}` (row has {} fields)",
                        rec.len()
                    ))
                })
            };
            let num = |c: usize, name: &str| -> Result<f64, DatasetError> {
                let s = field(c, name)?;
                let v: f64 = s
                    .parse()
                    .map_err(|_| bad(format!("`{name}` is `{s}`, expected a number")))?;
                if !v.is_finite() {
                    return Err(bad(format!("`{name}` is `{s}`, expected a finite number")));
                }
                match column_range(name) {
                    Some((lo, hi, what)) if !(lo..=hi).contains(&v) => Err(bad(format!(
                        "`{name}` is `{s}`, outside the range of {what}: {lo} to {hi}"
                    ))),
                    _ => Ok(v),
                }
            };
            let int = |c: usize, name: &str| -> Result<usize, DatasetError> {
                let s = field(c, name)?;
                match s.parse::<usize>() {
                    Ok(v) if v >= 1 => Ok(v),
                    _ => Err(bad(format!(
                        "`{name}` is `{s}`, expected a whole number from 1"
                    ))),
                }
            };
            let opt = |c: Option<usize>, name: &str| -> Result<Option<f64>, DatasetError> {
                match c {
                    Some(c) if rec.get(c).is_some_and(|s| !s.is_empty()) => num(c, name).map(Some),
                    _ => Ok(None),
                }
            };
            let direction = match field(c_dir, "direction")? {
                "+" | "up" | "Up" => Direction::Up,
                "-" | "down" | "Down" => Direction::Down,
                s => return Err(bad(format!("`direction` is `{s}`, expected `+` or `-`"))),
            };
            // An empty deviation is a reading lost to a beam interruption: skipped, and reported
            // by the analysis as missing.
            if rec.get(c_dev).is_some_and(|s| s.is_empty()) {
                continue;
            }
            let time_s = match c_time {
                Some(c) => num(c, "time_s")?,
                None => row_no as f64,
            };
            readings.push(Reading {
                cycle: int(c_cycle, "cycle")?,
                direction,
                index: int(c_index, "index")?,
                target_mm: num(c_target, "target_mm")?,
                deviation_um: num(c_dev, "deviation_um")?,
                time_s,
                air_c: opt(c_air, "air_c")?,
                material_c: opt(c_mat, "material_c")?,
            });
        }
        let alpha_um_per_m_k = parse_alpha(&metadata)?;
        for key in ["target_unit", "deviation_unit"] {
            if let Some(v) = metadata.get(key)
                && !crate::units::is_plain_unit(v)
            {
                return Err(DatasetError::BadMetadata {
                    key: key.into(),
                    value: v.clone(),
                    message: "a unit is 1 to 12 letters, digits or the signs µ ° ' \" / · ^ -                               (e.g. deg, mdeg, arcsec, µrad)"
                        .into(),
                });
            }
        }
        let material_compensation = !matches!(
            metadata
                .get("material_compensation")
                .map(|s| s.to_ascii_lowercase())
                .as_deref(),
            Some("off" | "false" | "no")
        );
        if readings.is_empty() {
            return Err(DatasetError::Empty);
        }
        Ok(PositioningData {
            axis: metadata.get("axis").cloned(),
            alpha_um_per_m_k,
            material_compensation,
            has_times: c_time.is_some(),
            metadata,
            readings,
        })
    }

    /// Passes that visit their targets against their direction: a `+` pass must visit them
    /// upwards (docs/datasets.md, "Direction labels").
    /// Only runs with real times whose passes are taken in one go are judged: in row order (no
    /// times) a pass may be listed in any order, and a run that repeats each target before the
    /// next has no passes.
    pub fn pass_direction_notes(&self) -> Vec<String> {
        if !self.has_times {
            return Vec::new();
        }
        let mut order: Vec<&Reading> = self.readings.iter().collect();
        order.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
        let mut passes: BTreeMap<(usize, usize), Vec<(usize, f64)>> = BTreeMap::new();
        for (rank, r) in order.iter().enumerate() {
            passes
                .entry((r.cycle, dir_slot(r.direction)))
                .or_default()
                .push((rank, r.target_mm));
        }
        let mut against = Vec::new();
        for ((cycle, slot), pass) in passes {
            let in_one_go = pass.last().map(|l| l.0) == pass.first().map(|f| f.0 + pass.len() - 1);
            if !in_one_go {
                continue;
            }
            let sign = if slot == 0 { 1.0 } else { -1.0 };
            let steps = pass.windows(2).map(|w| sign * (w[1].1 - w[0].1));
            let (up, down) = steps.fold((0, 0), |(u, d), s| {
                (u + usize::from(s > 0.0), d + usize::from(s < 0.0))
            });
            if pass.len() >= 3 && down > up {
                against.push(format!("{cycle}{}", if slot == 0 { "+" } else { "-" }));
            }
        }
        if against.is_empty() {
            return Vec::new();
        }
        vec![format!(
            "the passes {} visit their targets against their direction (a `+` pass goes up): \
             are the direction labels swapped? (docs/datasets.md, \"Direction labels\")",
            against.join(", ")
        )]
    }

    /// Checks what the analysis relies on: readings exist, a target number always names the
    /// same programmed position in one direction, and no reading is given twice. The two
    /// directions may approach a target at slightly different positions (some controllers log
    /// the backward pass shifted): up to a quarter of the smallest target spacing is accepted
    /// and the run is evaluated by target index ([`Self::direction_target_offset`] says by how
    /// much; `docs/datasets.md`, "Positioning dataset").
    pub fn validate(&self) -> Result<(), DatasetError> {
        if self.readings.is_empty() {
            return Err(DatasetError::Empty);
        }
        // Target and cycle numbers count up from 1; numbers far beyond the readings are a
        // damaged file, and the analyses size their tables by them (the `positioning_csv`
        // fuzz target found an index of 4 333 333 333 333 333 aborting on allocation).
        let n = self.readings.len();
        if let Some(r) = self.readings.iter().find(|r| r.index > n || r.cycle > n) {
            return Err(DatasetError::Inconsistent(format!(
                "target {} in cycle {}: target and cycle numbers count 1, 2, 3, ..., and the \
                 file has only {n} readings",
                r.index, r.cycle
            )));
        }
        let mut pos: BTreeMap<(usize, usize), f64> = BTreeMap::new();
        let mut seen = std::collections::HashSet::new();
        for r in &self.readings {
            let p = *pos
                .entry((r.index, dir_slot(r.direction)))
                .or_insert(r.target_mm);
            if (p - r.target_mm).abs() > 1e-3 {
                return Err(DatasetError::Inconsistent(format!(
                    "target {} ({}) is at {} mm in one row and {} mm in another",
                    r.index,
                    dir_sign(r.direction),
                    p,
                    r.target_mm
                )));
            }
            if !seen.insert((r.cycle, r.direction, r.index)) {
                return Err(DatasetError::Inconsistent(format!(
                    "cycle {} direction {} target {} is given twice",
                    r.cycle,
                    dir_sign(r.direction),
                    r.index
                )));
            }
        }
        check_distinct_targets(&pos)?;
        if let Some((index, d)) = self.direction_target_offset() {
            let t = self.targets_mm();
            let spacing = t
                .windows(2)
                .map(|w| (w[1] - w[0]).abs())
                .filter(|s| s.is_finite() && *s > 0.0)
                .fold(f64::INFINITY, f64::min);
            if d.abs() > 0.25 * spacing {
                return Err(DatasetError::Inconsistent(format!(
                    "target {index} is approached {d:+} mm apart in the two directions, more \
                     than a quarter of the smallest target spacing ({spacing} mm): are the \
                     target numbers of the two directions the same targets?"
                )));
            }
        }
        Ok(())
    }

    /// The largest difference between the positions at which the two directions approach the
    /// same target number, `(index, negative − positive in mm)`, when it exceeds 1 µm.
    pub fn direction_target_offset(&self) -> Option<(usize, f64)> {
        let mut pos: BTreeMap<usize, [Option<f64>; 2]> = BTreeMap::new();
        for r in &self.readings {
            pos.entry(r.index).or_default()[dir_slot(r.direction)] = Some(r.target_mm);
        }
        pos.iter()
            .filter_map(|(i, p)| Some((*i, p[1]? - p[0]?)))
            .filter(|(_, d)| d.abs() > 1e-3)
            .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
    }

    /// A sentence for reports when the directions approach the targets at different positions.
    pub fn direction_target_note(&self) -> Option<String> {
        self.direction_target_offset().map(|(i, d)| {
            format!(
                "the two directions approach the targets at different positions (largest \
                 difference {d:+.4} mm, target {i}): evaluated by target index, each target at \
                 the mean of its two positions"
            )
        })
    }

    /// Number of cycles (largest cycle number).
    pub fn n_cycles(&self) -> usize {
        self.readings.iter().map(|r| r.cycle).max().unwrap_or(0)
    }

    /// Number of targets (largest target number).
    pub fn n_targets(&self) -> usize {
        self.readings.iter().map(|r| r.index).max().unwrap_or(0)
    }

    /// Programmed targets by index (0-based position = index − 1), mm; NaN if never seen.
    /// Where the two directions approach a target at different positions, their mean.
    pub fn targets_mm(&self) -> Vec<f64> {
        let mut p = vec![[None::<f64>; 2]; self.n_targets()];
        for r in &self.readings {
            p[r.index - 1][dir_slot(r.direction)] = Some(r.target_mm);
        }
        p.iter()
            .map(|p| match p {
                [Some(a), Some(b)] => 0.5 * (a + b),
                [Some(a), None] | [None, Some(a)] => *a,
                [None, None] => f64::NAN,
            })
            .collect()
    }

    /// Readings as a grid `[direction][target][cycle]` (direction 0 = up), `None` where missing.
    pub fn grid(&self) -> [Vec<Vec<Option<f64>>>; 2] {
        let (m, n) = (self.n_targets(), self.n_cycles());
        let mut g = [vec![vec![None; n]; m], vec![vec![None; n]; m]];
        for r in &self.readings {
            g[dir_slot(r.direction)][r.index - 1][r.cycle - 1] = Some(r.deviation_um);
        }
        g
    }

    /// Times as a grid like [`Self::grid`].
    pub fn time_grid(&self) -> [Vec<Vec<Option<f64>>>; 2] {
        let (m, n) = (self.n_targets(), self.n_cycles());
        let mut g = [vec![vec![None; n]; m], vec![vec![None; n]; m]];
        for r in &self.readings {
            g[dir_slot(r.direction)][r.index - 1][r.cycle - 1] = Some(r.time_s);
        }
        g
    }

    /// Readings expected in a full run but absent: `(cycle, direction, index)`.
    pub fn missing(&self) -> Vec<(usize, Direction, usize)> {
        let g = self.grid();
        let mut out = Vec::new();
        for c in 0..self.n_cycles() {
            for (d, dir) in [(0, Direction::Up), (1, Direction::Down)] {
                // A direction never measured at all is not "missing" (unidirectional test).
                if g[d].iter().all(|t| t.iter().all(|v| v.is_none())) {
                    continue;
                }
                for (i, row) in g[d].iter().enumerate() {
                    if row[c].is_none() {
                        out.push((c + 1, dir, i + 1));
                    }
                }
            }
        }
        out
    }

    /// Writes the dataset as CSV (`docs/datasets.md`).
    pub fn to_csv_string(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        if let Some(a) = &self.axis {
            let _ = writeln!(s, "# axis: {a}");
        }
        if let Some(a) = self.alpha_um_per_m_k {
            let _ = writeln!(s, "# alpha_um_per_m_k: {a}");
        }
        if !self.material_compensation {
            let _ = writeln!(s, "# material_compensation: off");
        }
        // The unit lines of a rotary run (deg, mdeg…): the column names keep `_mm`/`_um`.
        let (u, d) = (self.units(), crate::units::Units::default());
        if u != d {
            let _ = writeln!(
                s,
                "# target_unit: {}\n# deviation_unit: {}",
                u.target, u.deviation
            );
        }
        let temps = self
            .readings
            .iter()
            .any(|r| r.air_c.is_some() || r.material_c.is_some());
        s.push_str("cycle,direction,index,target_mm,deviation_um");
        if self.has_times {
            s.push_str(",time_s");
        }
        if temps {
            s.push_str(",air_c,material_c");
        }
        s.push('\n');
        for r in &self.readings {
            let _ = write!(
                s,
                "{},{},{},{},{}",
                r.cycle,
                dir_sign(r.direction),
                r.index,
                r.target_mm,
                r.deviation_um
            );
            if self.has_times {
                let _ = write!(s, ",{}", r.time_s);
            }
            if temps {
                let f = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
                let _ = write!(s, ",{},{}", f(r.air_c), f(r.material_c));
            }
            s.push('\n');
        }
        s
    }
}

/// `0` for up, `1` for down: the slot of a direction in per-direction arrays.
/// A header that names a column twice is ambiguous (which `deviation_um` is meant?).
fn check_unique_columns(headers: &csv::StringRecord) -> Result<(), DatasetError> {
    for (i, h) in headers.iter().enumerate() {
        if h.is_empty() {
            continue;
        }
        if let Some(j) = headers
            .iter()
            .skip(i + 1)
            .position(|o| o.eq_ignore_ascii_case(h))
        {
            return Err(DatasetError::Inconsistent(format!(
                "the header names `{h}` twice (columns {} and {}): which one holds the data?",
                i + 1,
                i + j + 2
            )));
        }
    }
    Ok(())
}

fn parse_alpha(metadata: &BTreeMap<String, String>) -> Result<Option<f64>, DatasetError> {
    let Some(v) = metadata.get("alpha_um_per_m_k") else {
        return Ok(None);
    };
    match v.parse::<f64>() {
        Ok(a) if a.is_finite() && a.abs() <= MAX_ALPHA_UM_PER_M_K => Ok(Some(a)),
        _ => Err(DatasetError::BadMetadata {
            key: "alpha_um_per_m_k".into(),
            value: v.clone(),
            message: format!(
                "expected a finite number of µm/(m·K), at most {MAX_ALPHA_UM_PER_M_K} in size \
                 (steel 11.7, aluminium 23)"
            ),
        }),
    }
}

/// `s` with every control character but tab (a space) replaced by U+FFFD: a `# key: value` line is echoed into
/// the reports, and a control character there (an escape sequence, a carriage return) would
/// reach the terminal or a file another program reads.
fn printable(s: &str) -> String {
    s.chars()
        .map(|c| match c {
            '\t' => ' ',
            c if c.is_control() => '\u{fffd}',
            c => c,
        })
        .collect()
}

/// A note per metadata line (`# key: value`) holding control characters, which the reader
/// replaced.
fn control_character_notes(text: &str) -> Vec<String> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| l.trim_start().starts_with('#') && l.contains(':'))
        .filter(|(_, l)| l.chars().any(|c| c.is_control() && c != '\t'))
        .map(|(i, _)| {
            format!(
                "line {}: control characters in a `#` metadata line were replaced by \u{fffd}",
                i + 1
            )
        })
        .collect()
}

/// Renumbers cycles and targets 1, 2, 3, … in the order of their numbers when the file's do
/// not count so (cycles 10…50 would otherwise be read as 50 cycles, 9 of them missing), and
/// says how.
fn renumber(readings: &mut [Reading]) -> Vec<String> {
    let mut notes = Vec::new();
    for (what, get) in [
        (
            "cycle",
            (|r: &mut Reading| &mut r.cycle) as fn(&mut Reading) -> &mut usize,
        ),
        ("target", |r: &mut Reading| &mut r.index),
    ] {
        let mut numbers: Vec<usize> = readings.iter_mut().map(|r| *get(r)).collect();
        numbers.sort_unstable();
        numbers.dedup();
        if numbers.iter().enumerate().all(|(k, n)| *n == k + 1) {
            continue;
        }
        let to_new: BTreeMap<usize, usize> = numbers
            .iter()
            .enumerate()
            .map(|(k, n)| (*n, k + 1))
            .collect();
        for r in readings.iter_mut() {
            let n = get(r);
            *n = to_new.get(n).copied().unwrap_or(*n);
        }
        notes.push(format!(
            "{what} numbers {} do not count 1, 2, 3, …: read as {what}s 1 to {} in their order",
            number_list(&numbers),
            numbers.len()
        ));
    }
    notes
}

/// `3, 5, 6, …, 50` — the numbers of a list, shortened.
fn number_list(numbers: &[usize]) -> String {
    let shown: Vec<String> = numbers.iter().take(4).map(|n| n.to_string()).collect();
    match numbers.last() {
        Some(last) if numbers.len() > 5 => format!("{}, …, {last}", shown.join(", ")),
        _ => numbers
            .iter()
            .map(|n| n.to_string())
            .collect::<Vec<_>>()
            .join(", "),
    }
}

/// Two target numbers at one position in one direction are one target given twice.
fn check_distinct_targets(pos: &BTreeMap<(usize, usize), f64>) -> Result<(), DatasetError> {
    let mut by_dir: [Vec<(f64, usize)>; 2] = [Vec::new(), Vec::new()];
    for ((index, slot), p) in pos {
        by_dir[*slot].push((*p, *index));
    }
    for targets in &mut by_dir {
        targets.sort_by(|a, b| a.0.total_cmp(&b.0));
        if let Some(w) = targets.windows(2).find(|w| (w[1].0 - w[0].0).abs() < 1e-6) {
            return Err(DatasetError::Inconsistent(format!(
                "targets {} and {} are both at {} mm: each target number must name its own \
                 position",
                w[0].1, w[1].1, w[0].0
            )));
        }
    }
    Ok(())
}

pub fn dir_slot(d: Direction) -> usize {
    match d {
        Direction::Up => 0,
        Direction::Down => 1,
    }
}

/// `+` or `-`.
pub fn dir_sign(d: Direction) -> &'static str {
    match d {
        Direction::Up => "+",
        Direction::Down => "-",
    }
}

/// When each reading of a run is taken: what [`simulate`] needs to repeat a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScheduledReading {
    pub cycle: usize,
    pub direction: Direction,
    /// Target number, 1..m.
    pub index: usize,
    pub time_s: f64,
    pub material_c: Option<f64>,
    pub air_c: Option<f64>,
}

/// The schedule of an existing run (to simulate "the same run").
pub fn schedule_of(data: &PositioningData) -> Vec<ScheduledReading> {
    data.readings
        .iter()
        .map(|r| ScheduledReading {
            cycle: r.cycle,
            direction: r.direction,
            index: r.index,
            time_s: r.time_s,
            material_c: r.material_c,
            air_c: r.air_c,
        })
        .collect()
}

/// The usual ISO 230-2 schedule: `n_cycles` cycles, each an up pass over targets 1..m then a
/// down pass m..1, one reading every `reading_interval_s`.
pub fn standard_schedule(
    n_targets: usize,
    n_cycles: usize,
    reading_interval_s: f64,
) -> Vec<ScheduledReading> {
    let mut out = Vec::with_capacity(2 * n_targets * n_cycles);
    let mut t = 0.0;
    for c in 1..=n_cycles {
        for (dir, order) in [
            (Direction::Up, (1..=n_targets).collect::<Vec<_>>()),
            (Direction::Down, (1..=n_targets).rev().collect()),
        ] {
            for i in order {
                out.push(ScheduledReading {
                    cycle: c,
                    direction: dir,
                    index: i,
                    time_s: t,
                    material_c: None,
                    air_c: None,
                });
                t += reading_interval_s;
            }
        }
    }
    out
}

/// Simulates an [`AxisModel`] over a schedule: deterministic part + Gaussian noise (with the
/// model's local anomaly) + outliers of random sign, reproducibly from `seed`. Pure: the same
/// model, schedule and seed give the same data.
pub fn simulate(model: &AxisModel, schedule: &[ScheduledReading], seed: u64) -> PositioningData {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let outliers = model.outliers();
    // Offsets per cycle from their own stream, so that models without them simulate as before.
    let cycle_offsets: Vec<f64> = match model.cycle_offsets_std_um() {
        Some(s) => {
            let mut r2 = ChaCha8Rng::seed_from_u64(seed ^ 0x0ff5_e7c7_c1e5);
            let n = schedule.iter().map(|s| s.cycle).max().unwrap_or(0);
            (0..=n)
                .map(|_| {
                    let z: f64 = StandardNormal.sample(&mut r2);
                    s * z
                })
                .collect()
        }
        None => Vec::new(),
    };
    let readings = schedule
        .iter()
        .map(|s| {
            let i0 = s.index.saturating_sub(1);
            let mut dev = model.deterministic_um(i0, s.direction, s.time_s);
            dev += cycle_offsets.get(s.cycle).copied().unwrap_or(0.0);
            let z: f64 = StandardNormal.sample(&mut rng);
            dev += model.noise_std_um(i0) * z;
            if let Some((rate, mag)) = outliers {
                let u: f64 = rand::Rng::random(&mut rng);
                if u < rate {
                    let sign = if rand::Rng::random::<bool>(&mut rng) {
                        1.0
                    } else {
                        -1.0
                    };
                    dev += sign * mag;
                }
            }
            Reading {
                cycle: s.cycle,
                direction: s.direction,
                index: s.index,
                target_mm: model.targets_mm.get(i0).copied().unwrap_or(0.0),
                deviation_um: dev,
                time_s: s.time_s,
                air_c: s.air_c,
                material_c: s.material_c,
            }
        })
        .collect();
    PositioningData {
        axis: Some(model.axis.clone()),
        alpha_um_per_m_k: None,
        material_compensation: true,
        has_times: true,
        metadata: BTreeMap::new(),
        readings,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_come_from_metadata_and_markup_is_refused() {
        let rows = "cycle,direction,index,target_mm,deviation_um\n1,+,1,0,1\n1,+,2,10,2\n";
        let d = PositioningData::from_csv_str(rows).expect("plain");
        assert!(d.units().is_default());
        let text = format!("# target_unit: deg\n# deviation_unit: mdeg\n{rows}");
        let u = PositioningData::from_csv_str(&text)
            .expect("rotary")
            .units();
        assert_eq!((u.target.as_str(), u.deviation.as_str()), ("deg", "mdeg"));
        let bad = format!("# deviation_unit: <b>mdeg</b>\n{rows}");
        let e = PositioningData::from_csv_str(&bad).unwrap_err().to_string();
        assert!(
            e.contains("deviation_unit") && e.contains("e.g. deg"),
            "{e}"
        );
    }

    #[test]
    fn parses_any_column_order_metadata_and_missing() {
        let text = "# axis: Y\n# alpha_um_per_m_k: 11.7\n# material_compensation: off\n\
            deviation_um,index,cycle,direction,target_mm,extra\n\
            1.5,1,1,+,0.0,x\n\
            ,2,1,+,10.0,x\n\
            2.5,2,1,-,10.0,x\n";
        let d = PositioningData::from_csv_str(text).unwrap();
        assert_eq!(d.axis.as_deref(), Some("Y"));
        assert_eq!(d.alpha_um_per_m_k, Some(11.7));
        assert!(!d.material_compensation);
        assert!(!d.has_times);
        assert_eq!(d.readings.len(), 2);
        assert_eq!(d.readings[1].time_s, 2.0);
        assert_eq!(
            d.missing(),
            vec![(1, Direction::Up, 2), (1, Direction::Down, 1)]
        );
    }

    #[test]
    fn bad_rows_name_their_line() {
        let text = "# c\ncycle,direction,index,target_mm,deviation_um\n1,+,1,0,1\n1,*,2,5,1\n";
        let e = PositioningData::from_csv_str(text).unwrap_err().to_string();
        assert!(e.contains("line 4") && e.contains("direction"), "{e}");
        let text = "cycle,direction,index,target_mm,deviation_um\n1,+,1,0,abc\n";
        let e = PositioningData::from_csv_str(text).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("deviation_um"), "{e}");
        let text = "cycle,direction,target_mm,deviation_um\n1,+,0,1\n";
        let e = PositioningData::from_csv_str(text).unwrap_err().to_string();
        assert!(e.contains("`index`"), "{e}");
    }

    /// Two cycles of three targets, `+` up then `-` down, with the given cycle and target
    /// numbers.
    fn run(cycles: [usize; 2], targets: [usize; 3]) -> String {
        let mut t = String::from("cycle,direction,index,target_mm,deviation_um,time_s\n");
        let mut time = 0;
        for c in cycles {
            for (dir, order) in [("+", [0, 1, 2]), ("-", [2, 1, 0])] {
                for k in order {
                    time += 1;
                    t += &format!("{c},{dir},{},{},1.5,{time}\n", targets[k], 100 * k);
                }
            }
        }
        t
    }

    #[test]
    fn cycles_and_targets_that_do_not_count_from_one_are_renumbered_and_said_so() {
        let (d, notes) = PositioningData::from_csv_str_noted(&run([10, 50], [1, 2, 3])).unwrap();
        assert_eq!(d.n_cycles(), 2);
        assert!(d.missing().is_empty(), "{:?}", d.missing());
        assert!(
            notes.iter().any(|n| n.contains("cycle numbers 10, 50")),
            "{notes:?}"
        );
        let (d, notes) = PositioningData::from_csv_str_noted(&run([1, 2], [1, 2, 4])).unwrap();
        assert_eq!(d.n_targets(), 3);
        assert!(d.targets_mm().iter().all(|t| t.is_finite()));
        assert!(
            notes.iter().any(|n| n.contains("target numbers 1, 2, 4")),
            "{notes:?}"
        );
        let (_, notes) = PositioningData::from_csv_str_noted(&run([1, 2], [1, 2, 3])).unwrap();
        assert!(notes.is_empty(), "{notes:?}");
    }

    #[test]
    fn passes_against_their_direction_are_noted() {
        let swapped = run([1, 2], [1, 2, 3])
            .replace(",+,", ",x,")
            .replace(",-,", ",+,")
            .replace(",x,", ",-,");
        let (_, notes) = PositioningData::from_csv_str_noted(&swapped).unwrap();
        assert!(notes.iter().any(|n| n.contains("swapped")), "{notes:?}");
    }

    /// Found by the `positioning_path` fuzz target: control characters in a `# reference:`
    /// line reached the text and HTML reports (a terminal escape sequence, a carriage return).
    #[test]
    fn control_characters_in_metadata_are_replaced_and_noted() {
        let text = format!(
            "# reference: laser\u{1b}[2J\u{f}inf\u{f}\ttriang\r\n# axis: X\n{}",
            run([1, 2], [1, 2, 3])
        );
        let (d, notes) = PositioningData::from_csv_str_noted(&text).unwrap();
        assert_eq!(
            d.metadata["reference"],
            "laser\u{fffd}[2J\u{fffd}inf\u{fffd} triang"
        );
        assert!(
            d.metadata
                .values()
                .all(|v| !v.chars().any(char::is_control))
        );
        assert_eq!(
            notes,
            vec!["line 1: control characters in a `#` metadata line were replaced by \u{fffd}"]
        );
    }

    #[test]
    fn numbers_outside_their_physical_range_are_refused_with_the_line() {
        let huge = run([1, 2], [1, 2, 3]).replacen(",1.5,", ",1e155,", 1);
        let e = PositioningData::from_csv_str(&huge)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("deviation"), "{e}");
        let far = run([1, 2], [1, 2, 3]).replacen(",100,", ",1e308,", 1);
        let e = PositioningData::from_csv_str(&far).unwrap_err().to_string();
        assert!(e.contains("target_mm"), "{e}");
        let alpha = format!("# alpha_um_per_m_k: NaN\n{}", run([1, 2], [1, 2, 3]));
        let e = PositioningData::from_csv_str(&alpha)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("alpha_um_per_m_k") && e.contains("finite"),
            "{e}"
        );
    }

    #[test]
    fn a_column_named_twice_and_targets_at_one_position_are_refused() {
        let twice = run([1, 2], [1, 2, 3]).replacen("time_s", "deviation_um", 1);
        let e = PositioningData::from_csv_str(&twice)
            .unwrap_err()
            .to_string();
        assert!(e.contains("`deviation_um` twice"), "{e}");
        let one_place = run([1, 2], [1, 2, 3]).replace(",200,", ",100,");
        let e = PositioningData::from_csv_str(&one_place)
            .unwrap_err()
            .to_string();
        assert!(e.contains("both at 100 mm"), "{e}");
    }

    #[test]
    fn a_dataset_past_the_size_limit_is_refused() {
        let mut t = String::from("cycle,direction,index,target_mm,deviation_um\n");
        for k in 0..=MAX_READINGS {
            t += &format!("1,+,{},{k},0\n", k + 1);
        }
        let e = PositioningData::from_csv_str(&t).unwrap_err();
        assert!(matches!(e, DatasetError::TooLarge(MAX_READINGS)), "{e}");
    }
}
