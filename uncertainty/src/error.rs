//! Why an uncertainty evaluation could not be made.

use crate::expr;

/// Errors of uncertainty evaluation.
#[derive(Debug, thiserror::Error)]
pub enum UncertaintyError {
    /// the budget is not valid TOML or does not follow the budget format: {0}
    #[error("the budget is not valid TOML or does not follow the budget format: {0}")]
    Format(String),
    /// input `{input}`: {reason}
    #[error("input `{input}`: {reason}")]
    BadDistribution { input: String, reason: String },
    /// the expression of `{quantity}` is wrong {error}
    #[error("the expression of `{quantity}` is wrong {error}")]
    Expr {
        quantity: String,
        /// Not a `source`: the message above already says it (anyhow's `{:#}` printed it twice).
        error: expr::ExprError,
    },
    /// the name `{0}` is used twice (inputs, intermediates and outputs need distinct names)
    #[error("the name `{0}` is used twice (inputs, intermediates and outputs need distinct names)")]
    DuplicateName(String),
    /// a correlation names `{0}`, which is not an input
    #[error("a correlation names `{0}`, which is not an input")]
    UnknownInput(String),
    /// the correlation matrix is not positive definite: check the [[correlation]] coefficients
    #[error(
        "the correlation matrix is not positive definite: check the [[correlation]] coefficients"
    )]
    NotPositiveDefinite,
    /// output `{output}` is not a finite number {context}: check the model's domain against the
    /// input distributions (a division by zero, a square root of a negative value, ...)
    #[error(
        "output `{output}` is not a finite number {context}: check the model's domain against the input distributions (a division by zero, a square root of a negative value, ...)"
    )]
    NonFinite { output: String, context: String },
    /// {0}
    #[error("{0}")]
    Invalid(String),
}
