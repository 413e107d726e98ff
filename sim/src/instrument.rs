//! Which simulated device: the name every part of the simulator calls a device by.

use serde::{Deserialize, Serialize};

/// The simulated devices (same names as `drivers::Instrument`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Device {
    /// LI-80 laser interferometer.
    Interferometer,
    /// CB-3 CapBall ADC.
    Capball,
    /// PSD-2 transimpedance board.
    Psd,
    /// SLCAN adapter with the CNC's exact-stop triggers.
    Trigger,
}

impl Device {
    pub const ALL: [Device; 4] = [
        Device::Interferometer,
        Device::Capball,
        Device::Psd,
        Device::Trigger,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Device::Interferometer => "interferometer",
            Device::Capball => "capball",
            Device::Psd => "psd",
            Device::Trigger => "trigger",
        }
    }

    /// File name of the stable symlink in the simulation directory.
    pub fn link_name(self) -> &'static str {
        match self {
            Device::Interferometer => "li80",
            Device::Capball => "cb3",
            Device::Psd => "psd2",
            Device::Trigger => "slcan",
        }
    }

    pub(crate) fn index(self) -> usize {
        self as usize
    }
}
