//! Analysis inputs from a run's MCAP log: the adapters between the log (`/pose` values,
//! `/interferometer/environment`, the trajectory and config attachments) and the pure
//! analyses of the maths crates (`positioning`, `geometry`, `diagnose`, `uncertainty`).
//!
//! - [`positioning_from_log`]: the ISO 230-2 positioning run on X as a [`PositioningData`]
//!   (`analyze positioning`, `diagnose`);
//! - [`capball_from_log`]: the CapBall poses with their volumetric errors (`identify capball`);
//! - [`psd_from_log`]: a PSD straightness segment, offset and slope removed;
//! - [`demo_report`]: all of it as the compact text the `demo` command prints at its end.
//!
//! [`PositioningData`]: ::positioning::positioning_data::PositioningData

pub mod capball;
mod contents;
pub mod diagnosis_text;
pub mod export;
#[doc(hidden)]
pub mod fuzzcheck;
pub mod html_report;
pub mod identify_text;
#[cfg(feature = "plot")]
pub mod plot;
pub mod positioning;
pub mod positioning_report;
pub mod psd;
pub mod report;
pub mod uncertainty_text;

pub use capball::{CapballFromLog, capball_from_log};
pub use positioning::{PositioningOptions, parse_pose_range, positioning_from_log};
pub use psd::{PsdSegment, psd_from_log, psd_from_log_with};
pub use report::demo_report;

pub use contents::{AnalysisError, LogContents, LoggedPose, is_mcap};
