//! Diagnosis: what metrolog's own simulation gets wrong about measured data, named, the model
//! extended, the gain measured on held-out data — for positioning runs ([`axis`]: the axis model
//! of `metrolog-positioning` against an ISO 230-2 run) and CapBall runs ([`capball`]: the
//! 14-parameter CapBall model of `metrolog-geometry`). Pure maths with no I/O.

pub mod axis;
pub mod capball;
