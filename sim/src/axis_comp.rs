//! A compensation table loaded into the simulated X axis, applied as the controller applies
//! it: the simulated machine's side of a compensate-and-verify loop (`metrolog sim
//! --apply-comp`, the demo's verification run).
//!
//! LinuxCNC screw compensation (`[JOINT_n] COMP_FILE`, `COMP_FILE_TYPE = 1`), written here from
//! LinuxCNC's documented behaviour, not from metrolog's table writer (`positioning::
//! compensation`), so the loop checks the writer against the controller's semantics:
//!
//! - `src/emc/motion/usrmotintf.cc`, `usrmotLoadComp`: each line is read with
//!   `sscanf("%lf %lf %lf")` as `nominal forward_trim reverse_trim` (mm, type 1: `forward_trim
//!   = nominal − forward`); reading **stops at the first line that is not three numbers**;
//! - `src/emc/motion/command.c`, `EMCMOT_SET_JOINT_COMP`: at most `EMCMOT_COMP_SIZE` (256)
//!   triplets, nominals increasing;
//! - `src/emc/motion/control.c`, `compute_screw_comp`: the trim of the current direction of
//!   motion, linear between entries, the end entry's value outside them, kept while the joint
//!   stands; `motor-pos-cmd = pos-cmd + trim`.
//!
//! The joint moves to `pos-cmd + trim`; the machine's own error then adds to that, so the
//! deviation the interferometer sees is the axis model's plus the trim (the error's change over
//! a trim of a few µm is neglected). The interferometer's datum is taken at home, so the trim
//! at home (forward: homing ends moving up) is subtracted.

use positioning::axis_model::Direction;

/// LinuxCNC's `EMCMOT_COMP_SIZE`: triplets per joint.
pub const MAX_TRIPLETS: usize = 256;

/// A LinuxCNC type-1 screw-compensation table as motion holds it.
#[derive(Debug, Clone, PartialEq)]
pub struct ScrewComp {
    /// Nominal positions, mm, increasing.
    pub nominal_mm: Vec<f64>,
    /// Trim added to the commanded position on positive moves, mm.
    pub forward_trim_mm: Vec<f64>,
    /// Trim added to the commanded position on negative moves, mm.
    pub reverse_trim_mm: Vec<f64>,
    /// Non-blank lines after the first line that is not three numbers: LinuxCNC ignores them.
    pub ignored_lines: usize,
}

/// Why a comp file cannot be loaded into the simulated axis.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CompFileError {
    #[error(
        "the comp file has no triplet before line {line} (`{text}`): LinuxCNC reads `nominal forward_trim reverse_trim` per line and stops at the first line that is not three numbers, so this table is empty; remove header or comment lines"
    )]
    Empty { line: usize, text: String },
    #[error("line {line}: `{text}` holds a number that is not finite")]
    NotFinite { line: usize, text: String },
    #[error(
        "line {line}: nominal {nominal} mm does not increase on the line before ({previous} mm); LinuxCNC refuses triplets out of order"
    )]
    NotIncreasing {
        line: usize,
        nominal: f64,
        previous: f64,
    },
    #[error("{0} triplets: LinuxCNC holds at most 256 per joint")]
    TooMany(usize),
}

/// The three leading numbers of a line, as `sscanf("%lf %lf %lf")` takes them (whitespace
/// separated, anything after the third ignored).
fn triplet(line: &str) -> Option<[f64; 3]> {
    let mut it = line.split_whitespace().map(|w| w.parse::<f64>().ok());
    Some([it.next()??, it.next()??, it.next()??])
}

impl ScrewComp {
    /// Reads a type-1 comp file as `usrmotLoadComp` does (see the module doc). Refuses what
    /// LinuxCNC would load as an empty table, non-finite numbers, nominals out of order and
    /// more than 256 triplets; lines after the first one that is not three numbers are
    /// counted in [`ScrewComp::ignored_lines`], as LinuxCNC silently drops them.
    pub fn from_linuxcnc(text: &str) -> Result<ScrewComp, CompFileError> {
        let mut t = ScrewComp {
            nominal_mm: Vec::new(),
            forward_trim_mm: Vec::new(),
            reverse_trim_mm: Vec::new(),
            ignored_lines: 0,
        };
        let lines: Vec<&str> = text.lines().collect();
        for (i, line) in lines.iter().enumerate() {
            let Some([n, f, r]) = triplet(line) else {
                if t.nominal_mm.is_empty() {
                    return Err(CompFileError::Empty {
                        line: i + 1,
                        text: line.trim().to_string(),
                    });
                }
                t.ignored_lines = lines[i..].iter().filter(|l| !l.trim().is_empty()).count();
                break;
            };
            if !(n.is_finite() && f.is_finite() && r.is_finite()) {
                return Err(CompFileError::NotFinite {
                    line: i + 1,
                    text: line.trim().to_string(),
                });
            }
            if let Some(&previous) = t.nominal_mm.last()
                && n <= previous
            {
                return Err(CompFileError::NotIncreasing {
                    line: i + 1,
                    nominal: n,
                    previous,
                });
            }
            t.nominal_mm.push(n);
            t.forward_trim_mm.push(f);
            t.reverse_trim_mm.push(r);
        }
        match t.nominal_mm.len() {
            0 => Err(CompFileError::Empty {
                line: lines.len() + 1,
                text: "end of file".into(),
            }),
            n if n > MAX_TRIPLETS => Err(CompFileError::TooMany(n)),
            _ => Ok(t),
        }
    }

    /// The trim motion adds at commanded position `x_mm` moving (or last moved) in `dir`, µm.
    pub fn trim_um(&self, x_mm: f64, dir: Direction) -> f64 {
        let ys = match dir {
            Direction::Up => &self.forward_trim_mm,
            Direction::Down => &self.reverse_trim_mm,
        };
        let xs = &self.nominal_mm;
        let n = xs.len();
        let mm = if n == 0 {
            0.0
        } else if x_mm <= xs[0] {
            ys[0]
        } else if x_mm >= xs[n - 1] {
            ys[n - 1]
        } else {
            // The entry pair around x: the last nominal at or below it.
            let k = xs.partition_point(|&p| p <= x_mm) - 1;
            ys[k] + (ys[k + 1] - ys[k]) * (x_mm - xs[k]) / (xs[k + 1] - xs[k])
        };
        mm * 1e3
    }

    /// The same table with every trim's sign turned: what a writer with the wrong sign would
    /// have produced (the negative control of the verification tests).
    pub fn negated(&self) -> ScrewComp {
        let neg = |v: &[f64]| v.iter().map(|x| -x).collect();
        ScrewComp {
            forward_trim_mm: neg(&self.forward_trim_mm),
            reverse_trim_mm: neg(&self.reverse_trim_mm),
            ..self.clone()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = "0.000000 0.000000 0.000000\n100.000000 -0.002000 -0.005000\n200.000000 -0.004000 -0.007000\n";

    #[test]
    fn reads_triplets_and_interpolates_per_direction() {
        let t = ScrewComp::from_linuxcnc(FILE).expect("valid");
        assert_eq!(t.nominal_mm, [0.0, 100.0, 200.0]);
        assert!((t.trim_um(50.0, Direction::Up) + 1.0).abs() < 1e-12);
        assert!((t.trim_um(150.0, Direction::Down) + 6.0).abs() < 1e-12);
        // Held outside the table.
        assert!((t.trim_um(-30.0, Direction::Down)).abs() < 1e-12);
        assert!((t.trim_um(250.0, Direction::Up) + 4.0).abs() < 1e-12);
        assert!((t.trim_um(100.0, Direction::Up) + 2.0).abs() < 1e-12);
        assert!((t.negated().trim_um(50.0, Direction::Up) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn stops_at_the_first_line_that_is_not_three_numbers() {
        let e = ScrewComp::from_linuxcnc(&format!("# comp of X\n{FILE}")).expect_err("header");
        assert!(matches!(e, CompFileError::Empty { line: 1, .. }), "{e}");
        assert!(e.to_string().contains("stops at the first line"), "{e}");
        let t = ScrewComp::from_linuxcnc(&format!("{FILE}300 1\n400 0 0\n\n")).expect("prefix");
        assert_eq!((t.nominal_mm.len(), t.ignored_lines), (3, 2));
        // sscanf takes the first three numbers of a line and ignores the rest.
        let t = ScrewComp::from_linuxcnc("0 0 0 junk\n1 0.001 0.002 3\n").expect("trailing");
        assert_eq!(t.nominal_mm, [0.0, 1.0]);
    }

    #[test]
    fn refuses_what_linuxcnc_would_not_hold() {
        assert!(matches!(
            ScrewComp::from_linuxcnc(""),
            Err(CompFileError::Empty { .. })
        ));
        assert!(matches!(
            ScrewComp::from_linuxcnc("0 0 0\n1 nan 0\n"),
            Err(CompFileError::NotFinite { line: 2, .. })
        ));
        assert!(matches!(
            ScrewComp::from_linuxcnc("0 0 0\n0 0 0\n"),
            Err(CompFileError::NotIncreasing { line: 2, .. })
        ));
        let many: String = (0..257).map(|i| format!("{i} 0 0\n")).collect();
        assert_eq!(
            ScrewComp::from_linuxcnc(&many),
            Err(CompFileError::TooMany(257))
        );
    }
}
