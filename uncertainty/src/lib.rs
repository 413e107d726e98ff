//! Uncertainty evaluation: the GUM law of propagation (JCGM 100) and the Monte Carlo method
//! with the adaptive procedure (JCGM 101), for models with several outputs.
//!
//! - [`dist`]: input distributions (normal, rectangular, triangular, arcsine, Student t,
//!   trapezoidal, periodic drift, constant).
//! - [`gum`]: sensitivities by central differences, combined standard uncertainty with
//!   correlations, Welch–Satterthwaite, coverage factor, the budget table.
//! - [`mc`]: adaptive Monte Carlo (§7.9), symmetric and shortest coverage intervals, validation
//!   of the GUM result (§8); parallel and reproducible for a seed whatever the thread count.
//! - [`budget`]: budgets written as TOML files with the model as expressions ([`expr`]).
//! - [`capball`]: the CapBall link-error Monte Carlo of paper 001 with the statistical and the
//!   cyclic drift models.
//! - [`normals`]: standard normal deviates four at a time (the per-point CapBall trials).
//! - [`length`]: the LI-80 length measurement budget (ISO/TR 230-9 style).
//! - [`psd`]: the Monte Carlo of the PSD frame's 13 errors (paper 003 Table 4).
//!
//! ```
//! use uncertainty::budget::Budget;
//! let b = Budget::from_toml(r#"
//!     title = "sum of two"
//!     [[input]]
//!     name = "a"
//!     distribution = "normal"
//!     mean = 1.0
//!     u = 0.3
//!     [[input]]
//!     name = "b"
//!     distribution = "rectangular"
//!     mean = 2.0
//!     half_width = 0.4
//!     [[output]]
//!     name = "y"
//!     expr = "a + b"
//! "#).unwrap();
//! let g = b.gum().unwrap();
//! assert!((g.outputs[0].estimate - 3.0).abs() < 1e-12);
//! let u = (0.3f64.powi(2) + 0.4f64.powi(2) / 3.0).sqrt();
//! assert!((g.outputs[0].standard_uncertainty - u).abs() < 1e-9);
//! ```

pub mod budget;
pub mod capball;
pub mod dist;
mod error;
pub mod expr;
pub mod gum;
pub mod length;
pub mod mc;
mod model;
pub mod normals;
pub mod psd;
pub mod psd_budget;

pub use budget::{Budget, Method, Report};
pub use dist::{Distribution, DriftShape};
pub use error::UncertaintyError;
pub use gum::{BudgetLine, Coverage, GumInput, GumOutput, GumResult};
pub use mc::{
    IntervalKind, McOptions, McOutput, McProgress, McResult, TrialSource, Validation, Verdict,
};
pub use model::{FnModel, Model};
