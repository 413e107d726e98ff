//! Steady-value detection: one value per programmed pose from a sampled signal.
