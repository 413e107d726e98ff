//! Helpers for the hardware-in-loop tests in `tests/tests/`: the real drivers against the
//! simulated instruments of `sim/` on pseudo-terminals.
