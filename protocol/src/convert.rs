//! Host-side conversions of instruments.md: LI-80 air and material compensation, CapBall
//! polynomial and sensor-to-machine transform, PSD position, gating, error map, head thermal
//! correction.
