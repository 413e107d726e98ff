//! The crate's one error type: what went wrong, where, and what to fix.

/// Errors of reading a dataset, fitting, predicting or evaluating.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ThermalError {
    /// The CSV has no header line (only comments or nothing).
    #[error(
        "the file has no header line: expected `time_s`, temperature columns ending `_c` and optionally `spindle_rpm` and displacement columns ending `_um`"
    )]
    NoHeader,
    /// A required column is missing or a column name is not understood.
    #[error("line {line}: {what}")]
    Header { line: usize, what: String },
    /// A data line is malformed.
    #[error("line {line}, column `{column}`: {what}")]
    Value {
        line: usize,
        column: String,
        what: String,
    },
    /// A data line has the wrong number of fields.
    #[error(
        "line {line}: {found} fields, the header has {expected}; every line needs one value per column"
    )]
    FieldCount {
        line: usize,
        found: usize,
        expected: usize,
    },
    /// The CSV layer failed (encoding, quoting).
    #[error("line {line}: {what}")]
    Csv { line: usize, what: String },
    /// Too few samples for what was asked.
    #[error("{what}")]
    TooFewSamples { what: String },
    /// The dataset does not fit the model (missing channel or sensor).
    #[error("{what}")]
    Mismatch { what: String },
    /// A computation gave a non-finite number; the result is refused.
    #[error(
        "a result came out non-finite ({what}); the data are probably degenerate (a constant or duplicated column)"
    )]
    NonFinite { what: String },
    /// Parameters out of their valid range.
    #[error("invalid parameter: {what}")]
    Parameter { what: String },
}
