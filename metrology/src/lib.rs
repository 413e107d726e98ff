//! metrolog's pure maths: no I/O, no async. Machine and error models, steady-value detection,
//! ISO 230-2 with thermal-drift elimination, identification, uncertainty, diagnosis.

// Simulation model of a linear axis (shared by sim/ and diagnose).
pub mod axis_model;
// Pitch-error compensation tables per controller dialect.
pub mod compensation;
// Steady-value detection (one value per pose).
pub mod steady;

// Positioning accuracy (paper 000, ISO 230-2): dataset, evaluation, drift elimination, diagnosis.
pub mod diagnose;
pub mod drift;
pub mod iso230;
pub mod positioning_data;
pub mod standards;
pub mod units;

// Machine error models and identification (papers 001, 003, 004).
pub mod capball;
// What the 14-parameter CapBall model gets wrong (docs/datasets.md, CapBall effects).
pub mod capball_diagnosis;
pub mod kinematics;
pub mod parts;
// Planning a positioning test: targets, cycle, part programs.
pub mod plan;
pub mod psd_frame;
pub mod volumetric;

// Uncertainty: GUM and adaptive Monte Carlo (JCGM 100 / 101).
pub mod uncertainty;
