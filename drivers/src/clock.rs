//! Device-clock fitting: a robust running fit of a device clock against the host clock.
