//! Diagnosis: what metrolog's own simulation gets wrong about measured data, named, the model
//! extended, the gain measured on held-out data. Pure maths with no I/O; `metrolog diagnose`
//! and the demo report call it, and the simulator reads its extended models.
//!
//! The public API is two modules, one per kind of run; everything below them is private:
//! - [`axis`]: a positioning run (ISO 230-2) against the axis model of `metrolog-positioning`:
//!   [`axis::diagnose`] gives a [`axis::Diagnosis`] (the report and the extended
//!   `AxisModel`); each [`axis::Finding`] carries the model's typed `Effect`.
//! - [`capball`]: CapBall runs against the 14-parameter model of `metrolog-geometry`:
//!   [`capball::diagnose`] gives a [`capball::CapballDiagnosis`]; each finding carries a
//!   typed `geometry::capball_effects::CapballEffect`.
//!
//! The reports serialise with the names of `docs/datasets.md` ("Diagnosis report").

#![warn(unreachable_pub)]

pub mod axis;
pub mod capball;
