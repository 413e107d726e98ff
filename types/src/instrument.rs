//! The instruments metrolog knows, and which of them give pose values.

use serde::{Deserialize, Serialize};

/// The instruments metrolog knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[cfg_attr(feature = "schemars", derive(schemars::JsonSchema))]
#[serde(rename_all = "snake_case")]
pub enum Instrument {
    Interferometer,
    Capball,
    Psd,
    Trigger,
    // A Modbus RTU temperature module (instruments.md §5): environment, not pose-valued.
    // (A plain comment: a doc comment on one variant makes schemars write `oneOf`, which the
    // viewers' JSON-schema reader does not take as a string field.)
    #[serde(rename = "temperature")]
    Thermometer,
}

impl Instrument {
    /// Every instrument, in the order of their `Ord`.
    pub const ALL: [Instrument; 5] = [
        Instrument::Interferometer,
        Instrument::Capball,
        Instrument::Psd,
        Instrument::Trigger,
        Instrument::Thermometer,
    ];

    /// The instruments whose samples give pose values (the CNC trigger delimits poses but
    /// measures nothing), in the order of their `Ord`.
    pub const POSE_VALUED: [Instrument; 3] = [
        Instrument::Interferometer,
        Instrument::Capball,
        Instrument::Psd,
    ];

    /// The name used in the configuration, the log and the status (the serde name).
    pub fn name(self) -> &'static str {
        match self {
            Instrument::Interferometer => "interferometer",
            Instrument::Capball => "capball",
            Instrument::Psd => "psd",
            Instrument::Trigger => "trigger",
            Instrument::Thermometer => "temperature",
        }
    }

    /// Whether the instrument gives pose values (see [`Instrument::POSE_VALUED`]).
    pub fn gives_pose_values(self) -> bool {
        !self.detector_channels().is_empty()
    }

    /// Names of the pose detector's channels of this instrument, in the order the detector
    /// takes them (the fields of its sample that make a pose value): the interferometer's
    /// compensated length, the CapBall's machine-frame errors, the PSD's spot position. Empty
    /// for the trigger and the temperature module.
    pub fn detector_channels(self) -> &'static [&'static str] {
        match self {
            Instrument::Interferometer => &["position_um"],
            Instrument::Capball => &["ex_um", "ey_um", "ez_um"],
            Instrument::Psd => &["x_um", "y_um"],
            Instrument::Trigger | Instrument::Thermometer => &[],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_the_serde_names_and_pose_instruments_have_channels() {
        for i in Instrument::ALL {
            assert_eq!(
                serde_json_name(i),
                i.name(),
                "serde name of {i:?} differs from name()"
            );
            assert_eq!(i.gives_pose_values(), Instrument::POSE_VALUED.contains(&i));
        }
        assert!(Instrument::ALL.is_sorted() && Instrument::POSE_VALUED.is_sorted());
        assert_eq!(Instrument::Capball.detector_channels().len(), 3);
    }

    fn serde_json_name(i: Instrument) -> String {
        serde_json::to_value(i)
            .unwrap()
            .as_str()
            .unwrap()
            .to_string()
    }
}
