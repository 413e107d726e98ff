//! Positioning of a linear or rotary axis (paper 000, ISO 230-2), pure maths with no I/O:
//!
//! - [`axis_model`]: the simulation model of an axis (its error effects), shared by the
//!   simulator and the diagnosis;
//! - [`positioning_data`] and [`units`]: the positioning dataset (CSV) and its units;
//! - [`iso230`], [`standards`]: ISO 230-2 and the national standards' evaluations;
//!   [`drift`]: thermal-drift elimination; [`iso230_uncertainty`]: the uncertainty of the
//!   ISO 230-2 results (Annex A, ISO/TR 230-9); [`conformance`]: the ISO 14253-1 decision;
//! - [`compensation`]: pitch-error compensation tables per controller dialect;
//! - [`plan`]: planning a positioning test (targets, cycle, part programs);
//! - [`parts`]: parts and tool offsets.

pub mod axis_model;
pub mod compensation;
pub mod conformance;
pub mod drift;
pub mod iso230;
pub mod iso230_uncertainty;
pub mod parts;
pub mod plan;
pub mod positioning_data;
pub mod standards;
pub mod units;
