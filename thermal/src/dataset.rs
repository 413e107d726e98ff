//! A thermal test read from CSV: time, optional spindle speed, temperatures, displacements.

use crate::error::ThermalError;
use serde::{Deserialize, Serialize};
use std::io::Read;

/// One thermal test: samples in time order.
///
/// Columns: `time_s` (strictly increasing), optional `spindle_rpm`, temperatures ending `_c`
/// (at least one), displacements ending `_um` (none for a dataset to predict). Other columns
/// are refused so that a typo does not silently drop a sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThermalDataset {
    /// Sample times in seconds.
    pub time_s: Vec<f64>,
    /// Spindle speed in rpm, one per sample, if the file has it.
    pub spindle_rpm: Option<Vec<f64>>,
    /// Temperature sensor names (the column names without `_c`).
    pub sensor_names: Vec<String>,
    /// Temperatures in °C: `temperatures_c[sensor][sample]`.
    pub temperatures_c: Vec<Vec<f64>>,
    /// Displacement channel names (the column names without `_um`).
    pub channel_names: Vec<String>,
    /// Displacements in µm: `displacements_um[channel][sample]`.
    pub displacements_um: Vec<Vec<f64>>,
}

#[derive(Clone, Copy)]
enum Col {
    Time,
    Rpm,
    Temp(usize),
    Disp(usize),
}

impl ThermalDataset {
    /// Reads a dataset from CSV text. `#` lines are comments.
    pub fn from_csv(text: &str) -> Result<Self, ThermalError> {
        Self::from_reader(text.as_bytes())
    }

    /// Reads a dataset from any reader of CSV text.
    pub fn from_reader<R: Read>(reader: R) -> Result<Self, ThermalError> {
        let mut rdr = csv::ReaderBuilder::new()
            .has_headers(false)
            .comment(Some(b'#'))
            .flexible(true)
            .trim(csv::Trim::All)
            .from_reader(reader);
        let mut records = rdr.records();
        let header = match records.next() {
            None => return Err(ThermalError::NoHeader),
            Some(r) => r.map_err(csv_error)?,
        };
        let header_line = line_of(&header);
        let names: Vec<String> = header.iter().map(str::to_string).collect();
        let (cols, mut ds) = parse_header(&names, header_line)?;
        for rec in records {
            let rec = rec.map_err(csv_error)?;
            ds.push_record(&rec, &cols, &names)?;
        }
        ds.check()?;
        Ok(ds)
    }

    fn push_record(
        &mut self,
        rec: &csv::StringRecord,
        cols: &[Col],
        names: &[String],
    ) -> Result<(), ThermalError> {
        let line = line_of(rec);
        if rec.len() != cols.len() {
            return Err(ThermalError::FieldCount {
                line,
                found: rec.len(),
                expected: cols.len(),
            });
        }
        for ((field, col), name) in rec.iter().zip(cols).zip(names) {
            let v = parse_value(field, line, name)?;
            match *col {
                Col::Time => self.push_time(v, line)?,
                Col::Rpm => self.spindle_rpm.get_or_insert_with(Vec::new).push(v),
                Col::Temp(i) => self.temperatures_c[i].push(v),
                Col::Disp(i) => self.displacements_um[i].push(v),
            }
        }
        Ok(())
    }

    fn push_time(&mut self, t: f64, line: usize) -> Result<(), ThermalError> {
        if let Some(&prev) = self.time_s.last()
            && t <= prev
        {
            return Err(ThermalError::Value {
                line,
                column: "time_s".into(),
                what: format!(
                    "time {t} s is not after the previous {prev} s; times must increase strictly"
                ),
            });
        }
        self.time_s.push(t);
        Ok(())
    }

    fn check(&self) -> Result<(), ThermalError> {
        if self.time_s.len() < 2 {
            return Err(ThermalError::TooFewSamples {
                what: format!("{} data line(s); at least 2 are needed", self.time_s.len()),
            });
        }
        Ok(())
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.time_s.len()
    }

    /// True when the dataset holds no sample.
    pub fn is_empty(&self) -> bool {
        self.time_s.is_empty()
    }

    /// The samples `range` as a dataset of their own (times kept as they are).
    pub fn slice(&self, range: std::ops::Range<usize>) -> Result<Self, ThermalError> {
        if range.end > self.len() || range.len() < 2 {
            return Err(ThermalError::TooFewSamples {
                what: format!("slice {range:?} of a dataset of {} samples", self.len()),
            });
        }
        let cut = |v: &Vec<f64>| v[range.clone()].to_vec();
        Ok(Self {
            time_s: cut(&self.time_s),
            spindle_rpm: self.spindle_rpm.as_ref().map(cut),
            sensor_names: self.sensor_names.clone(),
            temperatures_c: self.temperatures_c.iter().map(cut).collect(),
            channel_names: self.channel_names.clone(),
            displacements_um: self.displacements_um.iter().map(cut).collect(),
        })
    }

    /// The inputs (time, speed, temperatures) of `self` followed by those of `next`, whose
    /// sensors are looked up by name; no displacement.
    pub fn join_inputs(&self, next: &ThermalDataset) -> Result<Self, ThermalError> {
        let mismatch = |what: String| ThermalError::Mismatch { what };
        if let (Some(a), Some(b)) = (self.time_s.last(), next.time_s.first())
            && b <= a
        {
            return Err(mismatch(format!(
                "the data start at {b} s, not after the history's end at {a} s"
            )));
        }
        let mut temps = vec![];
        for (name, t) in self.sensor_names.iter().zip(&self.temperatures_c) {
            let j = next.sensor_index(name).ok_or_else(|| {
                mismatch(format!("sensor `{name}` of the history is not in the data"))
            })?;
            temps.push(t.iter().chain(&next.temperatures_c[j]).copied().collect());
        }
        let rpm = match (&self.spindle_rpm, &next.spindle_rpm) {
            (Some(a), Some(b)) => Some(a.iter().chain(b).copied().collect()),
            (None, None) => None,
            _ => {
                return Err(mismatch(
                    "`spindle_rpm` is in only one of history and data".into(),
                ));
            }
        };
        Ok(Self {
            time_s: self.time_s.iter().chain(&next.time_s).copied().collect(),
            spindle_rpm: rpm,
            sensor_names: self.sensor_names.clone(),
            temperatures_c: temps,
            channel_names: vec![],
            displacements_um: vec![],
        })
    }

    /// Index of a sensor by name.
    pub fn sensor_index(&self, name: &str) -> Option<usize> {
        self.sensor_names.iter().position(|n| n == name)
    }

    /// Index of a displacement channel by name.
    pub fn channel_index(&self, name: &str) -> Option<usize> {
        self.channel_names.iter().position(|n| n == name)
    }
}

fn parse_header(names: &[String], line: usize) -> Result<(Vec<Col>, ThermalDataset), ThermalError> {
    let mut ds = ThermalDataset {
        time_s: Vec::new(),
        spindle_rpm: None,
        sensor_names: Vec::new(),
        temperatures_c: Vec::new(),
        channel_names: Vec::new(),
        displacements_um: Vec::new(),
    };
    let mut cols = Vec::with_capacity(names.len());
    for name in names {
        if name.chars().any(char::is_control) {
            return Err(ThermalError::Header {
                line,
                what: format!(
                    "column name {name:?} holds a control character; names are printed in the reports and written into the model and prediction files"
                ),
            });
        }
        let col = classify(name, &mut ds, &cols, line)?;
        cols.push(col);
    }
    if !cols.iter().any(|c| matches!(c, Col::Time)) {
        return Err(ThermalError::Header {
            line,
            what: "no `time_s` column".into(),
        });
    }
    if ds.sensor_names.is_empty() {
        return Err(ThermalError::Header {
            line,
            what: "no temperature column (a name ending `_c`, e.g. `t1_c`)".into(),
        });
    }
    Ok((cols, ds))
}

fn classify(
    name: &str,
    ds: &mut ThermalDataset,
    seen: &[Col],
    line: usize,
) -> Result<Col, ThermalError> {
    let dup = |what: &str| ThermalError::Header {
        line,
        what: format!("column `{what}` appears twice"),
    };
    if name == "time_s" {
        return if seen.iter().any(|c| matches!(c, Col::Time)) {
            Err(dup(name))
        } else {
            Ok(Col::Time)
        };
    }
    if name == "spindle_rpm" {
        return if seen.iter().any(|c| matches!(c, Col::Rpm)) {
            Err(dup(name))
        } else {
            Ok(Col::Rpm)
        };
    }
    if let Some(base) = name.strip_suffix("_um").filter(|b| !b.is_empty()) {
        if ds.channel_names.iter().any(|n| n == base) {
            return Err(dup(name));
        }
        ds.channel_names.push(base.to_string());
        ds.displacements_um.push(Vec::new());
        return Ok(Col::Disp(ds.channel_names.len() - 1));
    }
    if let Some(base) = name.strip_suffix("_c").filter(|b| !b.is_empty()) {
        if ds.sensor_names.iter().any(|n| n == base) {
            return Err(dup(name));
        }
        ds.sensor_names.push(base.to_string());
        ds.temperatures_c.push(Vec::new());
        return Ok(Col::Temp(ds.sensor_names.len() - 1));
    }
    Err(ThermalError::Header {
        line,
        what: format!(
            "column `{name}` is not understood: use `time_s`, `spindle_rpm`, names ending `_c` (°C) or `_um` (µm)"
        ),
    })
}

fn parse_value(field: &str, line: usize, column: &str) -> Result<f64, ThermalError> {
    let err = |what: String| ThermalError::Value {
        line,
        column: column.to_string(),
        what,
    };
    let v: f64 = field
        .parse()
        .map_err(|_| err(format!("`{field}` is not a number")))?;
    if !v.is_finite() {
        return Err(err(format!("`{field}` is not a finite number")));
    }
    Ok(v)
}

fn line_of(rec: &csv::StringRecord) -> usize {
    rec.position().map_or(0, |p| p.line() as usize)
}

fn csv_error(e: csv::Error) -> ThermalError {
    let line = e.position().map_or(0, |p| p.line() as usize);
    ThermalError::Csv {
        line,
        what: e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "# a comment\ntime_s,spindle_rpm,x_um,t1_c,t2_c\n0,0,0.1,20,21\n15,1000,0.2,20.1,21.2\n# mid comment\n30,1000,0.4,20.3,21.3\n";

    #[test]
    fn reads_a_good_file() {
        let ds = ThermalDataset::from_csv(GOOD).unwrap();
        assert_eq!(ds.len(), 3);
        assert_eq!(ds.sensor_names, vec!["t1", "t2"]);
        assert_eq!(ds.channel_names, vec!["x"]);
        assert_eq!(ds.spindle_rpm.as_deref(), Some(&[0.0, 1000.0, 1000.0][..]));
        assert_eq!(ds.temperatures_c[1], vec![21.0, 21.2, 21.3]);
    }

    /// A name is printed in the reports: an escape sequence in it would reach the terminal.
    #[test]
    fn a_column_name_with_a_control_character_is_refused() {
        let e = ThermalDataset::from_csv("time_s,d\u{1b}[31m_um,t1_c\n0,0,20\n1,0,20\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("line 1: column name \"d\\u{1b}[31m_um\""),
            "{e}"
        );
        assert!(e.contains("control character"), "{e}");
    }

    #[test]
    fn displacements_may_be_absent() {
        let ds = ThermalDataset::from_csv("time_s,t1_c\n0,20\n1,20.5\n").unwrap();
        assert!(ds.channel_names.is_empty() && ds.spindle_rpm.is_none());
    }

    #[test]
    fn errors_name_the_line() {
        let bad = "time_s,t1_c\n0,20\n1,abc\n";
        let e = ThermalDataset::from_csv(bad).unwrap_err();
        assert!(matches!(e, ThermalError::Value { line: 3, .. }), "{e:?}");
        let back = "time_s,t1_c\n0,20\n0,21\n";
        let e = ThermalDataset::from_csv(back).unwrap_err();
        assert!(matches!(e, ThermalError::Value { line: 3, .. }), "{e}");
        let nan = "# c\ntime_s,t1_c\n0,20\n1,NaN\n";
        let e = ThermalDataset::from_csv(nan).unwrap_err();
        assert!(matches!(e, ThermalError::Value { line: 4, .. }), "{e}");
        let short = "time_s,t1_c\n0,20\n1\n";
        assert!(matches!(
            ThermalDataset::from_csv(short).unwrap_err(),
            ThermalError::FieldCount { line: 3, .. }
        ));
    }

    #[test]
    fn header_errors() {
        assert_eq!(
            ThermalDataset::from_csv("# only\n").unwrap_err(),
            ThermalError::NoHeader
        );
        assert!(matches!(
            ThermalDataset::from_csv("time_s,x_um\n0,1\n1,2\n"),
            Err(ThermalError::Header { .. })
        ));
        assert!(matches!(
            ThermalDataset::from_csv("t1_c\n0\n1\n"),
            Err(ThermalError::Header { .. })
        ));
        assert!(matches!(
            ThermalDataset::from_csv("time_s,t1_c,foo\n0,1,2\n"),
            Err(ThermalError::Header { .. })
        ));
        assert!(matches!(
            ThermalDataset::from_csv("time_s,t1_c,t1_c\n0,1,2\n"),
            Err(ThermalError::Header { .. })
        ));
    }

    proptest::proptest! {
        #[test]
        fn never_panics(s in "\\PC{0,200}") {
            let _ = ThermalDataset::from_csv(&s);
        }
    }
}
