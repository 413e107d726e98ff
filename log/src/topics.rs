//! The messages of each MCAP topic (docs/log-format.md).
//!
//! - `/pose`, `/status`, `/event`, `/cnc/trigger`: JSON, with a JSON schema generated from
//!   these types (`schemars`) and rewritten by [`viewer_schema`] into the subset Foxglove and
//!   Lichtblick load (no `$ref`, one scalar `type` per field, enums inline).
//! - The raw sample topics: protobuf batches ([`crate::raw`]) in logs written since format 2;
//!   one JSON message per sample ([`PositionMsg`], [`EnvironmentMsg`], [`CapballMsg`],
//!   [`PsdMsg`], log time = host arrival time) in older logs, still read by [`decode_message`].
//!
//! Every raw sample carries the device's `seq` and `device_t_us`, the clock-fitted time and
//! the host arrival time, so a log holds everything replay needs to re-run the steady-value
//! detection exactly.

use std::collections::BTreeMap;

use protocol::can::TriggerEvent;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize, de::DeserializeOwned};
use types::{Counters, Instrument, Sample, SampleValues, Trigger};
/// The `/pose` message and its time stamp are the detector's output type (`metrolog-types`).
pub use types::{PoseMsg, Stamp};

/// A message type bound to one topic.
pub trait TopicMessage: Serialize + DeserializeOwned + JsonSchema {
    const TOPIC: &'static str;
    /// Schema name in the MCAP schema record.
    const SCHEMA_NAME: &'static str;
}

macro_rules! topic {
    ($t:ty, $topic:literal, $schema:literal) => {
        impl TopicMessage for $t {
            const TOPIC: &'static str = $topic;
            const SCHEMA_NAME: &'static str = $schema;
        }
    };
}

/// Non-finite numbers (a PSD sample with no light divides by zero) are written as JSON `null`
/// — JSON has no NaN — and read back as NaN; the schema says `number` or `null`.
mod nullable {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_none()
        }
    }
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
    }

    pub mod array3 {
        use serde::ser::SerializeTuple;
        use serde::{Deserialize, Deserializer, Serializer};

        pub fn serialize<S: Serializer>(v: &[f64; 3], s: S) -> Result<S::Ok, S::Error> {
            let mut t = s.serialize_tuple(3)?;
            for x in v {
                t.serialize_element(&x.is_finite().then_some(*x))?;
            }
            t.end()
        }
        pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
            let a = <[Option<f64>; 3]>::deserialize(d)?;
            Ok(a.map(|x| x.unwrap_or(f64::NAN)))
        }
    }

    pub mod vec {
        use serde::{Deserialize, Deserializer, Serializer};

        pub fn serialize<S: Serializer>(v: &[f64], s: S) -> Result<S::Ok, S::Error> {
            s.collect_seq(v.iter().map(|x| x.is_finite().then_some(*x)))
        }
        pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
            let v = Vec::<Option<f64>>::deserialize(d)?;
            Ok(v.into_iter().map(|x| x.unwrap_or(f64::NAN)).collect())
        }
    }
}

/// `/interferometer/position`: one LI-80 `$POS` record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct PositionMsg {
    pub seq: u64,
    pub device_t_us: u64,
    /// Device time on the host axis (clock fit), ns since the Unix epoch.
    pub fitted_ns: u64,
    pub raw_nm: i64,
    /// Compensated length, µm.
    #[serde(with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub position_um: f64,
    /// Signal strength, %.
    pub sig: u8,
    pub flags: u32,
    pub valid: bool,
}
topic!(PositionMsg, "/interferometer/position", "metrolog.Position");

/// `/interferometer/environment`: one LI-80 `$ENV` record and the refractive index from it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct EnvironmentMsg {
    pub seq: u64,
    pub device_t_us: u64,
    pub fitted_ns: u64,
    #[serde(with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub air_c: f64,
    #[serde(with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub air_pa: f64,
    #[serde(with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub rh_pct: f64,
    #[serde(with = "nullable::vec")]
    #[schemars(with = "Vec<Option<f64>>")]
    pub material_c: Vec<f64>,
    #[serde(with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub n_air: f64,
    pub valid: bool,
}
topic!(
    EnvironmentMsg,
    "/interferometer/environment",
    "metrolog.Environment"
);

/// `/capball/sample`: one CB-3 sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct CapballMsg {
    pub seq: u64,
    pub device_t_us: u64,
    pub fitted_ns: u64,
    /// Sensor voltages, V.
    #[serde(with = "nullable::array3")]
    #[schemars(with = "[Option<f64>; 3]")]
    pub volts: [f64; 3],
    /// Distance changes of the three sensors, µm.
    #[serde(with = "nullable::array3")]
    #[schemars(with = "[Option<f64>; 3]")]
    pub d_um: [f64; 3],
    /// Ball-centre error in the machine frame (x, y, z), µm.
    #[serde(with = "nullable::array3")]
    #[schemars(with = "[Option<f64>; 3]")]
    pub e_um: [f64; 3],
    pub flags: u8,
    pub valid: bool,
}
topic!(CapballMsg, "/capball/sample", "metrolog.Capball");

/// `/psd/sample`: one PSD-2 sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct PsdMsg {
    pub seq: u64,
    pub device_t_us: u64,
    pub fitted_ns: u64,
    #[serde(with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub x_um: f64,
    #[serde(with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub y_um: f64,
    #[serde(with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub sum_pa: f64,
    #[serde(with = "nullable")]
    #[schemars(with = "Option<f64>")]
    pub head_c: f64,
    pub valid: bool,
}
topic!(PsdMsg, "/psd/sample", "metrolog.Psd");

/// `/cnc/trigger`: one CNC trigger frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct TriggerMsg {
    pub event: TriggerEvent,
    pub pose: u16,
    /// NC clock, ms (wraps).
    pub nc_ms: u32,
}
topic!(TriggerMsg, "/cnc/trigger", "metrolog.Trigger");

topic!(PoseMsg, "/pose", "metrolog.Pose");

/// Counters of one instrument (see `types::Counters`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct CountersMsg {
    pub samples: u64,
    pub gap_samples: u64,
    pub gaps: u64,
    /// Rejected records by kind (`bad_checksum`, `bad_crc`, ...).
    pub rejections: BTreeMap<String, u64>,
    pub resyncs: u64,
    pub reconnects: u64,
    pub disconnects: u64,
    pub dropped: u64,
    pub invalid: u64,
    pub device_errors: u64,
    pub answers: u64,
    /// Fitted drift of the device clock against the host clock, ppm; absent until the fit
    /// has enough points (never `null`: viewers want one scalar type per field).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock_drift_ppm: Option<f64>,
}

impl From<&Counters> for CountersMsg {
    fn from(c: &Counters) -> Self {
        CountersMsg {
            samples: c.samples,
            gap_samples: c.gap_samples,
            gaps: c.gaps,
            rejections: c
                .rejections
                .iter()
                .map(|(k, v)| (k.name().to_string(), *v))
                .collect(),
            resyncs: c.resyncs,
            reconnects: c.reconnects,
            disconnects: c.disconnects,
            dropped: c.dropped,
            invalid: c.invalid,
            device_errors: c.device_errors,
            answers: c.answers,
            clock_drift_ppm: c.clock_drift_ppm.filter(|d| d.is_finite()),
        }
    }
}

/// `/status`, about once a second: every instrument's counters and the log's own.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct StatusMsg {
    /// Counters by instrument name (`interferometer`, `capball`, `psd`, `trigger`,
    /// `temperature`).
    #[schemars(schema_with = "counters_map")]
    pub instruments: BTreeMap<String, CountersMsg>,
    /// Messages written to this log so far.
    pub log_messages: u64,
    /// Pose values emitted so far, by status.
    pub poses: BTreeMap<String, u64>,
}
topic!(StatusMsg, "/status", "metrolog.Status");

/// Schema of `/status` `instruments`: one optional [`CountersMsg`] per instrument name.
fn counters_map(g: &mut schemars::SchemaGenerator) -> schemars::Schema {
    let counters = g.subschema_for::<CountersMsg>();
    let props: serde_json::Map<String, serde_json::Value> =
        ["interferometer", "capball", "psd", "trigger"]
            .iter()
            .map(|n| (n.to_string(), counters.as_value().clone()))
            .collect();
    schemars::json_schema!({"type": "object", "properties": props})
}

/// What happened to a device connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    Connected,
    Disconnected,
    Error,
    // The interferometer's datum epoch changed: lost, or re-referenced (text says which).
    Datum,
}

/// `/event`: connections, disconnections and device errors, as text.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct EventMsg {
    pub instrument: String,
    pub kind: EventKind,
    pub port: String,
    /// Identity (connected), reason (disconnected), message (error), or for `datum`:
    /// `epoch <k> lost: <why>` or `epoch <k> referenced at pose <p>: <text>`.
    pub text: String,
}
topic!(EventMsg, "/event", "metrolog.Event");

impl Decoded {
    /// The message of a sample's raw topic.
    pub fn from_sample(s: &Sample) -> Decoded {
        let (seq, device_t_us, fitted_ns, valid) = (s.seq, s.device_t_us, s.fitted_ns, s.valid);
        match &s.values {
            SampleValues::Position {
                raw_nm,
                position_um,
                sig,
                flags,
            } => Decoded::Position(PositionMsg {
                seq,
                device_t_us,
                fitted_ns,
                raw_nm: *raw_nm,
                position_um: *position_um,
                sig: *sig,
                flags: *flags,
                valid,
            }),
            SampleValues::Environment {
                air_c,
                air_pa,
                rh_pct,
                material_c,
                n_air,
            } => Decoded::Environment(EnvironmentMsg {
                seq,
                device_t_us,
                fitted_ns,
                air_c: *air_c,
                air_pa: *air_pa,
                rh_pct: *rh_pct,
                material_c: material_c.clone(),
                n_air: *n_air,
                valid,
            }),
            SampleValues::Capball {
                volts,
                d_um,
                e_um,
                flags,
            } => Decoded::Capball(CapballMsg {
                seq,
                device_t_us,
                fitted_ns,
                volts: *volts,
                d_um: *d_um,
                e_um: *e_um,
                flags: *flags,
                valid,
            }),
            SampleValues::Psd {
                x_um,
                y_um,
                sum_pa,
                head_c,
            } => Decoded::Psd(PsdMsg {
                seq,
                device_t_us,
                fitted_ns,
                x_um: *x_um,
                y_um: *y_um,
                sum_pa: *sum_pa,
                head_c: *head_c,
                valid,
            }),
            SampleValues::Temperature { .. } => Decoded::Unlogged(s.instrument),
        }
    }

    /// The sample back, with `host_ns` = the message's log time; `None` for a message of
    /// another topic than the four raw sample topics.
    pub fn to_sample(&self, host_ns: u64) -> Option<Sample> {
        Some(match self {
            Decoded::Position(m) => Sample {
                instrument: Instrument::Interferometer,
                seq: m.seq,
                device_t_us: m.device_t_us,
                host_ns,
                fitted_ns: m.fitted_ns,
                valid: m.valid,
                values: SampleValues::Position {
                    raw_nm: m.raw_nm,
                    position_um: m.position_um,
                    sig: m.sig,
                    flags: m.flags,
                },
            },
            Decoded::Environment(m) => Sample {
                instrument: Instrument::Interferometer,
                seq: m.seq,
                device_t_us: m.device_t_us,
                host_ns,
                fitted_ns: m.fitted_ns,
                valid: m.valid,
                values: SampleValues::Environment {
                    air_c: m.air_c,
                    air_pa: m.air_pa,
                    rh_pct: m.rh_pct,
                    material_c: m.material_c.clone(),
                    n_air: m.n_air,
                },
            },
            Decoded::Capball(m) => Sample {
                instrument: Instrument::Capball,
                seq: m.seq,
                device_t_us: m.device_t_us,
                host_ns,
                fitted_ns: m.fitted_ns,
                valid: m.valid,
                values: SampleValues::Capball {
                    volts: m.volts,
                    d_um: m.d_um,
                    e_um: m.e_um,
                    flags: m.flags,
                },
            },
            Decoded::Psd(m) => Sample {
                instrument: Instrument::Psd,
                seq: m.seq,
                device_t_us: m.device_t_us,
                host_ns,
                fitted_ns: m.fitted_ns,
                valid: m.valid,
                values: SampleValues::Psd {
                    x_um: m.x_um,
                    y_um: m.y_um,
                    sum_pa: m.sum_pa,
                    head_c: m.head_c,
                },
            },
            _ => return None,
        })
    }
}

impl TriggerMsg {
    pub fn from_trigger(t: &Trigger) -> TriggerMsg {
        TriggerMsg {
            event: t.event,
            pose: t.pose,
            nc_ms: t.nc_ms,
        }
    }
    pub fn to_trigger(&self, host_ns: u64) -> Trigger {
        Trigger {
            event: self.event,
            pose: self.pose,
            nc_ms: self.nc_ms,
            host_ns,
        }
    }
}

/// Any message of a known topic, decoded.
#[derive(Debug, Clone, PartialEq)]
pub enum Decoded {
    Position(PositionMsg),
    Environment(EnvironmentMsg),
    Capball(CapballMsg),
    Psd(PsdMsg),
    Trigger(TriggerMsg),
    Pose(PoseMsg),
    Status(StatusMsg),
    Event(EventMsg),
    /// A sample of an instrument that has no JSON topic (the Modbus temperature module: logged
    /// in `/temperature` batches only, which format 1 predates); never decoded from a log.
    Unlogged(Instrument),
}

/// Decodes a message of one of metrolog's topics; `Ok(None)` for a topic it does not know.
pub fn decode(topic: &str, data: &[u8]) -> Result<Option<Decoded>, serde_json::Error> {
    Ok(Some(match topic {
        PositionMsg::TOPIC => Decoded::Position(serde_json::from_slice(data)?),
        EnvironmentMsg::TOPIC => Decoded::Environment(serde_json::from_slice(data)?),
        CapballMsg::TOPIC => Decoded::Capball(serde_json::from_slice(data)?),
        PsdMsg::TOPIC => Decoded::Psd(serde_json::from_slice(data)?),
        TriggerMsg::TOPIC => Decoded::Trigger(serde_json::from_slice(data)?),
        PoseMsg::TOPIC => Decoded::Pose(serde_json::from_slice(data)?),
        StatusMsg::TOPIC => Decoded::Status(serde_json::from_slice(data)?),
        EventMsg::TOPIC => Decoded::Event(serde_json::from_slice(data)?),
        _ => return Ok(None),
    }))
}

/// The JSON topics metrolog writes, with their schema names and viewer-safe JSON schemas
/// ([`viewer_schema`]). The raw sample topics are protobuf ([`crate::raw::RAW_TOPICS`]).
pub fn json_topics() -> Vec<(&'static str, &'static str, serde_json::Value)> {
    fn one<T: TopicMessage>() -> (&'static str, &'static str, serde_json::Value) {
        (
            T::TOPIC,
            T::SCHEMA_NAME,
            viewer_schema(&schemars::schema_for!(T)),
        )
    }
    vec![
        one::<TriggerMsg>(),
        one::<PoseMsg>(),
        one::<StatusMsg>(),
        one::<EventMsg>(),
    ]
}

/// A JSON schema rewritten into the subset the viewers load (Lichtblick's and Foxglove's
/// `parseJsonSchema` accept an object root whose fields each have one scalar `type`, and
/// follow no `$ref`): references to `$defs` are inlined, enums become
/// `{"type": "string", "enum": [...]}`, and `null` is dropped from type lists (metrolog never
/// writes `null` in these topics: an absent value is an absent field).
pub fn viewer_schema(schema: &schemars::Schema) -> serde_json::Value {
    let mut root = schema.as_value().clone();
    let defs = root
        .as_object_mut()
        .and_then(|o| o.remove("$defs"))
        .unwrap_or_default();
    inline(&mut root, &defs, 0);
    root
}

fn inline(v: &mut serde_json::Value, defs: &serde_json::Value, depth: usize) {
    use serde_json::Value;
    match v {
        Value::Object(o) => {
            if let Some(Value::String(r)) = o.get("$ref").cloned()
                && depth < 32
                && let Some(Value::Object(def)) =
                    r.strip_prefix("#/$defs/").and_then(|name| defs.get(name))
            {
                o.remove("$ref");
                for (k, x) in def {
                    o.entry(k.clone()).or_insert_with(|| x.clone());
                }
                return inline(v, defs, depth + 1);
            }
            // `Option<T>`: `anyOf: [T, {"type": "null"}]` → T.
            for key in ["anyOf", "oneOf"] {
                if let Some(Value::Array(alts)) = o.get(key) {
                    let not_null: Vec<Value> = alts
                        .iter()
                        .filter(|a| a.get("type") != Some(&Value::from("null")))
                        .cloned()
                        .collect();
                    let strings: Option<Vec<Value>> = not_null
                        .iter()
                        .map(|a| {
                            a.get("const").cloned().or_else(|| {
                                a.get("enum")
                                    .and_then(|e| e.as_array())
                                    .filter(|e| e.len() == 1)
                                    .map(|e| e[0].clone())
                            })
                        })
                        .collect();
                    if let Some(values) = strings.filter(|s| s.iter().all(Value::is_string)) {
                        o.remove(key);
                        o.insert("type".into(), "string".into());
                        o.insert("enum".into(), Value::Array(values));
                    } else if not_null.len() == 1 {
                        o.remove(key);
                        if let Value::Object(only) = &not_null[0] {
                            for (k, x) in only {
                                o.entry(k.clone()).or_insert_with(|| x.clone());
                            }
                        }
                    }
                }
            }
            // A map (`additionalProperties` only): viewers read `properties` of every object.
            if o.get("type") == Some(&Value::from("object")) && !o.contains_key("properties") {
                o.insert("properties".into(), Value::Object(Default::default()));
            }
            if let Some(Value::Array(types)) = o.get("type") {
                let kept: Vec<Value> = types
                    .iter()
                    .filter(|t| *t != &Value::from("null"))
                    .cloned()
                    .collect();
                if kept.len() == 1 {
                    o.insert("type".into(), kept[0].clone());
                }
            }
            for x in o.values_mut() {
                inline(x, defs, depth + 1);
            }
        }
        Value::Array(a) => a.iter_mut().for_each(|x| inline(x, defs, depth + 1)),
        _ => {}
    }
}

/// Why a message did not decode.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    #[error("bad JSON: {0}")]
    Json(#[from] serde_json::Error),
    #[error("bad protobuf batch: {0}")]
    Protobuf(#[from] crate::raw::BatchError),
}

/// A message of one of metrolog's topics, decoded, whatever the log format.
#[derive(Debug, Clone, PartialEq)]
pub enum LogMessage {
    /// Raw samples (one from an old JSON log, a batch from a protobuf one), each with its host
    /// arrival time.
    Samples(Vec<Sample>),
    Trigger(TriggerMsg),
    Pose(PoseMsg),
    Status(StatusMsg),
    Event(EventMsg),
}

/// Decodes a message of one of metrolog's topics, JSON (old and current logs) or protobuf
/// (raw batches of format 2 or 3); `log_ns` is the message's log time, the host time of an old JSON sample.
/// `Ok(None)` for a topic it does not know.
pub fn decode_message(
    topic: &str,
    encoding: &str,
    log_ns: u64,
    data: &[u8],
) -> Result<Option<LogMessage>, DecodeError> {
    if encoding == "protobuf" {
        return match crate::raw::Batch::decode(topic, data)? {
            Some(b) => Ok(Some(LogMessage::Samples(b.samples()?))),
            None => Ok(None),
        };
    }
    Ok(decode(topic, data)?.map(|d| match d {
        Decoded::Trigger(t) => LogMessage::Trigger(t),
        Decoded::Pose(p) => LogMessage::Pose(p),
        Decoded::Status(s) => LogMessage::Status(s),
        Decoded::Event(e) => LogMessage::Event(e),
        raw => LogMessage::Samples(raw.to_sample(log_ns).into_iter().collect()),
    }))
}
