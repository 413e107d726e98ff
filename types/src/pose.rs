//! What the steady-value detector gives per instrument and pose.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::Instrument;

/// Why a pose could not be measured, or `Ok`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "schemars", derive(schemars::JsonSchema))]
#[serde(rename_all = "snake_case")]
pub enum PoseStatus {
    Ok,
    /// The signal did not settle before the next motion.
    NeverSteady,
    /// Too few valid samples (beam interrupted, over-range, off the diode).
    BeamInvalid,
    /// The device delivered no samples during the dwell (unplugged, stopped).
    DeviceAway,
    /// An exact-stop trigger was expected but missing (detected from motion/dwell triggers).
    TriggerMissing,
    /// The instrument's zero is no longer the run's: the interferometer lost its datum (beam
    /// interrupted) or came back from a reconnect (power-cycled or re-zeroed), so its lengths
    /// are not comparable with the run's earlier ones; re-reference before using them.
    DatumLost,
    /// The interferometer's steady value is farther from its pose's target than the machine's
    /// errors can be (`DetectorSettings::position_targets`): the dwell took another pose's
    /// samples, or the zero is not the datum. Not a measurement of this pose.
    OffTarget,
}

impl PoseStatus {
    pub fn name(self) -> &'static str {
        match self {
            PoseStatus::Ok => "ok",
            PoseStatus::NeverSteady => "never_steady",
            PoseStatus::BeamInvalid => "beam_invalid",
            PoseStatus::DeviceAway => "device_away",
            PoseStatus::TriggerMissing => "trigger_missing",
            PoseStatus::DatumLost => "datum_lost",
            PoseStatus::OffTarget => "off_target",
        }
    }
    pub fn from_name(name: &str) -> Option<PoseStatus> {
        [
            PoseStatus::Ok,
            PoseStatus::NeverSteady,
            PoseStatus::BeamInvalid,
            PoseStatus::DeviceAway,
            PoseStatus::TriggerMissing,
            PoseStatus::DatumLost,
            PoseStatus::OffTarget,
        ]
        .into_iter()
        .find(|s| s.name() == name)
    }
}

/// One steady value of one instrument at one pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseValue {
    pub pose: u32,
    pub status: PoseStatus,
    /// Samples averaged (0 when no window was found).
    pub n: usize,
    /// Per channel mean, in the channel order the detector was built with (empty when n = 0).
    pub mean: Vec<f64>,
    /// Per channel sample standard deviation (empty when n = 0).
    pub std: Vec<f64>,
    /// Host times of the first and last averaged sample, ns since the Unix epoch (or the dwell
    /// bounds when n = 0).
    pub t_first_ns: u64,
    pub t_last_ns: u64,
}

/// `/pose`: the steady value of one instrument at one pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schemars", derive(schemars::JsonSchema))]
pub struct PoseMsg {
    /// One of the instruments that give pose values (`Instrument::POSE_VALUED`).
    pub instrument: Instrument,
    pub pose: u32,
    pub status: PoseStatus,
    /// Samples averaged (0 when no value).
    pub n: u64,
    /// Mean per channel, by channel name (`position_um`; `ex_um`, `ey_um`, `ez_um`; `x_um`,
    /// `y_um`); empty when no value.
    #[cfg_attr(feature = "schemars", schemars(schema_with = "channel_map"))]
    pub mean: BTreeMap<String, f64>,
    /// Sample standard deviation per channel.
    #[cfg_attr(feature = "schemars", schemars(schema_with = "channel_map"))]
    pub std: BTreeMap<String, f64>,
    /// First and last averaged sample (or the dwell bounds), ns since the Unix epoch; in the
    /// JSON `t_first`/`t_last` as `{sec, nsec}` (the Foxglove time convention: a JavaScript
    /// viewer would round an integer of ns); format-1 logs wrote `t_first_ns`/`t_last_ns`.
    #[serde(rename = "t_first", alias = "t_first_ns", with = "stamp")]
    #[cfg_attr(feature = "schemars", schemars(with = "Stamp"))]
    pub t_first_ns: u64,
    #[serde(rename = "t_last", alias = "t_last_ns", with = "stamp")]
    #[cfg_attr(feature = "schemars", schemars(with = "Stamp"))]
    pub t_last_ns: u64,
    /// The interferometer's datum epoch the value was measured in (0: the run's datum; a
    /// reconnect, a beam loss or a service start mid-program starts the next; docs/design.md,
    /// "Datum epochs"). 0 for the other instruments and in logs written before epochs.
    #[serde(default)]
    pub datum_epoch: u32,
}

/// A time in the Foxglove JSON convention: seconds and nanoseconds since the Unix epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schemars", derive(schemars::JsonSchema))]
pub struct Stamp {
    pub sec: u32,
    pub nsec: u32,
}

/// ns since the epoch as a [`Stamp`]; read back from a `Stamp` or a plain integer of ns
/// (format-1 logs).
mod stamp {
    use super::Stamp;
    use serde::{Deserialize, Deserializer, Serializer};

    pub(super) fn serialize<S: Serializer>(ns: &u64, s: S) -> Result<S::Ok, S::Error> {
        let st = Stamp {
            sec: u32::try_from(ns / 1_000_000_000).unwrap_or(u32::MAX),
            nsec: (ns % 1_000_000_000) as u32,
        };
        serde::Serialize::serialize(&st, s)
    }

    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Either {
        Ns(u64),
        Stamp(Stamp),
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
        Ok(match Either::deserialize(d)? {
            Either::Ns(ns) => ns,
            Either::Stamp(st) => u64::from(st.sec) * 1_000_000_000 + u64::from(st.nsec),
        })
    }
}

/// Schema of a per-channel map of `/pose`: every channel name of every instrument, as an
/// optional number (viewers list an object's fields from `properties`).
#[cfg(feature = "schemars")]
fn channel_map(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
    let props: serde_json::Map<String, serde_json::Value> = Instrument::POSE_VALUED
        .iter()
        .flat_map(|i| i.detector_channels())
        .map(|c| (c.to_string(), serde_json::json!({"type": "number"})))
        .collect();
    schemars::json_schema!({"type": "object", "properties": props})
}

impl PoseMsg {
    pub fn from_value(instrument: Instrument, v: &PoseValue) -> PoseMsg {
        let names = instrument.detector_channels();
        let map = |xs: &[f64]| {
            names
                .iter()
                .zip(xs)
                .map(|(n, x)| (n.to_string(), *x))
                .collect::<BTreeMap<_, _>>()
        };
        PoseMsg {
            instrument,
            pose: v.pose,
            status: v.status,
            n: v.n as u64,
            mean: map(&v.mean),
            std: map(&v.std),
            t_first_ns: v.t_first_ns,
            t_last_ns: v.t_last_ns,
            datum_epoch: 0,
        }
    }
}
