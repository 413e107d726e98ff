//! The raw sample topics as protobuf batches (docs/log-format.md).
//!
//! One MCAP message holds the samples of one instrument topic over at most
//! [`LogOptions::batch_interval`](crate::LogOptions) (10 ms) of host time, column by column:
//! `header` holds, per sample, the device `seq`, the device clock `device_t_us`, the fitted
//! time and the host arrival time (`google.protobuf.Timestamp`, the Foxglove convention: no
//! integer beyond 2^53 reaches a JavaScript viewer as a number it would round) and the validity;
//! the value columns follow (`position_um`, `ex_um`, ...), one entry per sample. Every value of
//! [`Sample`] is kept, so a batch gives back exactly the samples that went in (replay reproduces
//! the logged `/pose` values bit for bit).
//!
//! The schema of each channel is a `FileDescriptorSet` ([`descriptor_set`]) built here by hand
//! from the same field list as the `prost` messages below; the log crate's tests and the
//! viewers' own protobuf reader (`protobufjs`, in the node check of `daemon/tests`) decode
//! the messages with it.

use drivers::{Instrument, Sample, SampleValues};
use prost::Message;
use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{
    DescriptorProto, FieldDescriptorProto, FileDescriptorProto, FileDescriptorSet, Timestamp,
};

/// Topics of the raw samples (the same names as the JSON topics of older logs).
pub const POSITION_TOPIC: &str = "/interferometer/position";
pub const ENVIRONMENT_TOPIC: &str = "/interferometer/environment";
pub const CAPBALL_TOPIC: &str = "/capball/sample";
pub const PSD_TOPIC: &str = "/psd/sample";

/// Per-sample columns common to every raw batch.
#[derive(Clone, PartialEq, prost::Message)]
pub struct BatchHeader {
    #[prost(uint64, repeated, tag = "1")]
    pub seq: Vec<u64>,
    #[prost(uint64, repeated, tag = "2")]
    pub device_t_us: Vec<u64>,
    /// Device time on the host axis (clock fit).
    #[prost(message, repeated, tag = "3")]
    pub fitted_time: Vec<Timestamp>,
    /// Host arrival time.
    #[prost(message, repeated, tag = "4")]
    pub host_time: Vec<Timestamp>,
    #[prost(bool, repeated, tag = "5")]
    pub valid: Vec<bool>,
}

/// `/interferometer/position`: LI-80 `$POS` records.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PositionBatch {
    #[prost(message, optional, tag = "1")]
    pub header: Option<BatchHeader>,
    #[prost(sint64, repeated, tag = "2")]
    pub raw_nm: Vec<i64>,
    #[prost(double, repeated, tag = "3")]
    pub position_um: Vec<f64>,
    #[prost(uint32, repeated, tag = "4")]
    pub sig: Vec<u32>,
    #[prost(uint32, repeated, tag = "5")]
    pub flags: Vec<u32>,
}

/// `/interferometer/environment`: LI-80 `$ENV` records; `material_c` holds the material
/// temperatures of all samples one after the other, `material_count[i]` of sample `i`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct EnvironmentBatch {
    #[prost(message, optional, tag = "1")]
    pub header: Option<BatchHeader>,
    #[prost(double, repeated, tag = "2")]
    pub air_c: Vec<f64>,
    #[prost(double, repeated, tag = "3")]
    pub air_pa: Vec<f64>,
    #[prost(double, repeated, tag = "4")]
    pub rh_pct: Vec<f64>,
    #[prost(double, repeated, tag = "5")]
    pub n_air: Vec<f64>,
    #[prost(double, repeated, tag = "6")]
    pub material_c: Vec<f64>,
    #[prost(uint32, repeated, tag = "7")]
    pub material_count: Vec<u32>,
}

/// `/capball/sample`: CB-3 samples.
#[derive(Clone, PartialEq, prost::Message)]
pub struct CapballBatch {
    #[prost(message, optional, tag = "1")]
    pub header: Option<BatchHeader>,
    #[prost(double, repeated, tag = "2")]
    pub volts_1: Vec<f64>,
    #[prost(double, repeated, tag = "3")]
    pub volts_2: Vec<f64>,
    #[prost(double, repeated, tag = "4")]
    pub volts_3: Vec<f64>,
    #[prost(double, repeated, tag = "5")]
    pub d1_um: Vec<f64>,
    #[prost(double, repeated, tag = "6")]
    pub d2_um: Vec<f64>,
    #[prost(double, repeated, tag = "7")]
    pub d3_um: Vec<f64>,
    #[prost(double, repeated, tag = "8")]
    pub ex_um: Vec<f64>,
    #[prost(double, repeated, tag = "9")]
    pub ey_um: Vec<f64>,
    #[prost(double, repeated, tag = "10")]
    pub ez_um: Vec<f64>,
    #[prost(uint32, repeated, tag = "11")]
    pub flags: Vec<u32>,
}

/// `/psd/sample`: PSD-2 samples.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PsdBatch {
    #[prost(message, optional, tag = "1")]
    pub header: Option<BatchHeader>,
    #[prost(double, repeated, tag = "2")]
    pub x_um: Vec<f64>,
    #[prost(double, repeated, tag = "3")]
    pub y_um: Vec<f64>,
    #[prost(double, repeated, tag = "4")]
    pub sum_pa: Vec<f64>,
    #[prost(double, repeated, tag = "5")]
    pub head_c: Vec<f64>,
}

/// ns since the Unix epoch as a `Timestamp` (exact both ways).
pub fn timestamp(ns: u64) -> Timestamp {
    Timestamp {
        seconds: (ns / 1_000_000_000) as i64,
        nanos: (ns % 1_000_000_000) as i32,
    }
}

fn timestamp_ns(t: &Timestamp) -> Result<u64, String> {
    if t.seconds < 0 || !(0..1_000_000_000).contains(&t.nanos) {
        return Err(format!(
            "timestamp {}.{:09} is outside the log's range",
            t.seconds, t.nanos
        ));
    }
    (t.seconds as u64)
        .checked_mul(1_000_000_000)
        .and_then(|s| s.checked_add(t.nanos as u64))
        .ok_or_else(|| format!("timestamp {} s overflows", t.seconds))
}

impl BatchHeader {
    fn push(&mut self, s: &Sample) {
        self.seq.push(s.seq);
        self.device_t_us.push(s.device_t_us);
        self.fitted_time.push(timestamp(s.fitted_ns));
        self.host_time.push(timestamp(s.host_ns));
        self.valid.push(s.valid);
    }

    /// The header of sample `i`: (seq, device_t_us, fitted_ns, host_ns, valid).
    fn get(&self, i: usize) -> Result<(u64, u64, u64, u64, bool), String> {
        Ok((
            self.seq[i],
            self.device_t_us[i],
            timestamp_ns(&self.fitted_time[i])?,
            timestamp_ns(&self.host_time[i])?,
            self.valid[i],
        ))
    }
}

/// Samples of one raw topic waiting to be written as one message.
#[derive(Debug, Clone, PartialEq)]
pub enum Batch {
    Position(PositionBatch),
    Environment(EnvironmentBatch),
    Capball(CapballBatch),
    Psd(PsdBatch),
}

/// The topic of a sample.
pub fn topic_of(s: &Sample) -> &'static str {
    match s.values {
        SampleValues::Position { .. } => POSITION_TOPIC,
        SampleValues::Environment { .. } => ENVIRONMENT_TOPIC,
        SampleValues::Capball { .. } => CAPBALL_TOPIC,
        SampleValues::Psd { .. } => PSD_TOPIC,
    }
}

impl Batch {
    /// An empty batch of the topic of `s`.
    pub fn for_sample(s: &Sample) -> Batch {
        match s.values {
            SampleValues::Position { .. } => Batch::Position(Default::default()),
            SampleValues::Environment { .. } => Batch::Environment(Default::default()),
            SampleValues::Capball { .. } => Batch::Capball(Default::default()),
            SampleValues::Psd { .. } => Batch::Psd(Default::default()),
        }
    }

    pub fn topic(&self) -> &'static str {
        match self {
            Batch::Position(_) => POSITION_TOPIC,
            Batch::Environment(_) => ENVIRONMENT_TOPIC,
            Batch::Capball(_) => CAPBALL_TOPIC,
            Batch::Psd(_) => PSD_TOPIC,
        }
    }

    fn header(&self) -> Option<&BatchHeader> {
        match self {
            Batch::Position(b) => b.header.as_ref(),
            Batch::Environment(b) => b.header.as_ref(),
            Batch::Capball(b) => b.header.as_ref(),
            Batch::Psd(b) => b.header.as_ref(),
        }
    }

    /// Samples in the batch.
    pub fn len(&self) -> usize {
        self.header().map_or(0, |h| h.seq.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Appends `s`; false (and nothing appended) when `s` belongs to another topic.
    pub fn push(&mut self, s: &Sample) -> bool {
        match (self, &s.values) {
            (
                Batch::Position(b),
                SampleValues::Position {
                    raw_nm,
                    position_um,
                    sig,
                    flags,
                },
            ) => {
                b.header.get_or_insert_default().push(s);
                b.raw_nm.push(*raw_nm);
                b.position_um.push(*position_um);
                b.sig.push(u32::from(*sig));
                b.flags.push(*flags);
            }
            (
                Batch::Environment(b),
                SampleValues::Environment {
                    air_c,
                    air_pa,
                    rh_pct,
                    material_c,
                    n_air,
                },
            ) => {
                b.header.get_or_insert_default().push(s);
                b.air_c.push(*air_c);
                b.air_pa.push(*air_pa);
                b.rh_pct.push(*rh_pct);
                b.n_air.push(*n_air);
                b.material_c.extend_from_slice(material_c);
                b.material_count.push(material_c.len() as u32);
            }
            (
                Batch::Capball(b),
                SampleValues::Capball {
                    volts,
                    d_um,
                    e_um,
                    flags,
                },
            ) => {
                b.header.get_or_insert_default().push(s);
                for (col, x) in [&mut b.volts_1, &mut b.volts_2, &mut b.volts_3]
                    .into_iter()
                    .zip(volts)
                {
                    col.push(*x);
                }
                for (col, x) in [&mut b.d1_um, &mut b.d2_um, &mut b.d3_um]
                    .into_iter()
                    .zip(d_um)
                {
                    col.push(*x);
                }
                for (col, x) in [&mut b.ex_um, &mut b.ey_um, &mut b.ez_um]
                    .into_iter()
                    .zip(e_um)
                {
                    col.push(*x);
                }
                b.flags.push(u32::from(*flags));
            }
            (
                Batch::Psd(b),
                SampleValues::Psd {
                    x_um,
                    y_um,
                    sum_pa,
                    head_c,
                },
            ) => {
                b.header.get_or_insert_default().push(s);
                b.x_um.push(*x_um);
                b.y_um.push(*y_um);
                b.sum_pa.push(*sum_pa);
                b.head_c.push(*head_c);
            }
            _ => return false,
        }
        true
    }

    /// Host arrival time of the first sample (the message's log time).
    pub fn first_host_ns(&self) -> Option<u64> {
        self.header()
            .and_then(|h| h.host_time.first())
            .and_then(|t| timestamp_ns(t).ok())
    }

    /// The protobuf encoding, appended to `buf`.
    pub fn encode(&self, buf: &mut Vec<u8>) {
        // Encoding into a Vec cannot fail (it grows).
        let _ = match self {
            Batch::Position(b) => b.encode(buf),
            Batch::Environment(b) => b.encode(buf),
            Batch::Capball(b) => b.encode(buf),
            Batch::Psd(b) => b.encode(buf),
        };
    }

    /// Empties the batch, keeping its allocations.
    pub fn clear(&mut self) {
        match self {
            Batch::Position(b) => b.clear(),
            Batch::Environment(b) => b.clear(),
            Batch::Capball(b) => b.clear(),
            Batch::Psd(b) => b.clear(),
        }
    }

    /// Decodes a message of a raw topic; `Ok(None)` for another topic.
    pub fn decode(topic: &str, data: &[u8]) -> Result<Option<Batch>, String> {
        let e = |e: prost::DecodeError| e.to_string();
        Ok(Some(match topic {
            POSITION_TOPIC => Batch::Position(PositionBatch::decode(data).map_err(e)?),
            ENVIRONMENT_TOPIC => Batch::Environment(EnvironmentBatch::decode(data).map_err(e)?),
            CAPBALL_TOPIC => Batch::Capball(CapballBatch::decode(data).map_err(e)?),
            PSD_TOPIC => Batch::Psd(PsdBatch::decode(data).map_err(e)?),
            _ => return Ok(None),
        }))
    }

    /// The samples back, in order. A batch whose columns differ in length is an error.
    pub fn samples(&self) -> Result<Vec<Sample>, String> {
        let Some(h) = self.header() else {
            return Ok(Vec::new());
        };
        let n = h.seq.len();
        let mut lens = vec![
            h.device_t_us.len(),
            h.fitted_time.len(),
            h.host_time.len(),
            h.valid.len(),
        ];
        match self {
            Batch::Position(b) => {
                lens.extend([b.raw_nm.len(), b.position_um.len(), b.sig.len()]);
                lens.push(b.flags.len());
            }
            Batch::Environment(b) => {
                lens.extend([b.air_c.len(), b.air_pa.len(), b.rh_pct.len()]);
                lens.extend([b.n_air.len(), b.material_count.len()]);
                let total: u64 = b.material_count.iter().map(|&c| u64::from(c)).sum();
                if total != b.material_c.len() as u64 {
                    return Err(format!(
                        "material_count adds up to {total}, material_c has {}",
                        b.material_c.len()
                    ));
                }
            }
            Batch::Capball(b) => {
                lens.extend([b.volts_1.len(), b.volts_2.len(), b.volts_3.len()]);
                lens.extend([b.d1_um.len(), b.d2_um.len(), b.d3_um.len()]);
                lens.extend([b.ex_um.len(), b.ey_um.len(), b.ez_um.len()]);
                lens.push(b.flags.len());
            }
            Batch::Psd(b) => {
                lens.extend([b.x_um.len(), b.y_um.len(), b.sum_pa.len(), b.head_c.len()]);
            }
        }
        if let Some(bad) = lens.iter().find(|&&l| l != n) {
            return Err(format!(
                "a {} batch has columns of {n} and {bad} samples",
                self.topic()
            ));
        }
        let mut out = Vec::with_capacity(n);
        let mut material = 0usize;
        for i in 0..n {
            let (seq, device_t_us, fitted_ns, host_ns, valid) = h.get(i)?;
            let (instrument, values) = match self {
                Batch::Position(b) => (
                    Instrument::Interferometer,
                    SampleValues::Position {
                        raw_nm: b.raw_nm[i],
                        position_um: b.position_um[i],
                        sig: u8::try_from(b.sig[i]).map_err(|_| "sig above 255".to_string())?,
                        flags: b.flags[i],
                    },
                ),
                Batch::Environment(b) => {
                    let k = b.material_count[i] as usize;
                    let m = b.material_c[material..material + k].to_vec();
                    material += k;
                    (
                        Instrument::Interferometer,
                        SampleValues::Environment {
                            air_c: b.air_c[i],
                            air_pa: b.air_pa[i],
                            rh_pct: b.rh_pct[i],
                            material_c: m,
                            n_air: b.n_air[i],
                        },
                    )
                }
                Batch::Capball(b) => (
                    Instrument::Capball,
                    SampleValues::Capball {
                        volts: [b.volts_1[i], b.volts_2[i], b.volts_3[i]],
                        d_um: [b.d1_um[i], b.d2_um[i], b.d3_um[i]],
                        e_um: [b.ex_um[i], b.ey_um[i], b.ez_um[i]],
                        flags: u8::try_from(b.flags[i])
                            .map_err(|_| "flags above 255".to_string())?,
                    },
                ),
                Batch::Psd(b) => (
                    Instrument::Psd,
                    SampleValues::Psd {
                        x_um: b.x_um[i],
                        y_um: b.y_um[i],
                        sum_pa: b.sum_pa[i],
                        head_c: b.head_c[i],
                    },
                ),
            };
            out.push(Sample {
                instrument,
                seq,
                device_t_us,
                host_ns,
                fitted_ns,
                valid,
                values,
            });
        }
        Ok(out)
    }
}

/// The raw topics with their schema (message) names.
pub const RAW_TOPICS: [(&str, &str); 4] = [
    (POSITION_TOPIC, "metrolog.PositionBatch"),
    (ENVIRONMENT_TOPIC, "metrolog.EnvironmentBatch"),
    (CAPBALL_TOPIC, "metrolog.CapballBatch"),
    (PSD_TOPIC, "metrolog.PsdBatch"),
];

fn field(name: &str, number: i32, ty: Type, type_name: Option<&str>) -> FieldDescriptorProto {
    FieldDescriptorProto {
        name: Some(name.into()),
        number: Some(number),
        label: Some(Label::Repeated as i32),
        r#type: Some(ty as i32),
        type_name: type_name.map(str::to_string),
        json_name: Some(name.into()),
        ..Default::default()
    }
}

fn message(name: &str, fields: Vec<FieldDescriptorProto>) -> DescriptorProto {
    DescriptorProto {
        name: Some(name.into()),
        field: fields,
        ..Default::default()
    }
}

/// Value columns after `header` (tag 1), from tag 2 on, all of one type.
fn batch(name: &str, columns: &[(&str, Type)]) -> DescriptorProto {
    let mut fields = vec![FieldDescriptorProto {
        label: Some(Label::Optional as i32),
        ..field("header", 1, Type::Message, Some(".metrolog.BatchHeader"))
    }];
    fields.extend(
        columns
            .iter()
            .enumerate()
            .map(|(i, (n, t))| field(n, i as i32 + 2, *t, None)),
    );
    message(name, fields)
}

/// The `FileDescriptorSet` of the raw topics (`metrolog/raw.proto` and the
/// `google/protobuf/timestamp.proto` it imports), the schema data of every raw channel.
pub fn descriptor_set() -> Vec<u8> {
    let timestamp = FileDescriptorProto {
        name: Some("google/protobuf/timestamp.proto".into()),
        package: Some("google.protobuf".into()),
        message_type: vec![message(
            "Timestamp",
            vec![
                FieldDescriptorProto {
                    label: Some(Label::Optional as i32),
                    ..field("seconds", 1, Type::Int64, None)
                },
                FieldDescriptorProto {
                    label: Some(Label::Optional as i32),
                    ..field("nanos", 2, Type::Int32, None)
                },
            ],
        )],
        syntax: Some("proto3".into()),
        ..Default::default()
    };
    let ts = Some(".google.protobuf.Timestamp");
    let header = message(
        "BatchHeader",
        vec![
            field("seq", 1, Type::Uint64, None),
            field("device_t_us", 2, Type::Uint64, None),
            field("fitted_time", 3, Type::Message, ts),
            field("host_time", 4, Type::Message, ts),
            field("valid", 5, Type::Bool, None),
        ],
    );
    let d = Type::Double;
    let raw = FileDescriptorProto {
        name: Some("metrolog/raw.proto".into()),
        package: Some("metrolog".into()),
        dependency: vec!["google/protobuf/timestamp.proto".into()],
        message_type: vec![
            header,
            batch(
                "PositionBatch",
                &[
                    ("raw_nm", Type::Sint64),
                    ("position_um", d),
                    ("sig", Type::Uint32),
                    ("flags", Type::Uint32),
                ],
            ),
            batch(
                "EnvironmentBatch",
                &[
                    ("air_c", d),
                    ("air_pa", d),
                    ("rh_pct", d),
                    ("n_air", d),
                    ("material_c", d),
                    ("material_count", Type::Uint32),
                ],
            ),
            batch(
                "CapballBatch",
                &[
                    ("volts_1", d),
                    ("volts_2", d),
                    ("volts_3", d),
                    ("d1_um", d),
                    ("d2_um", d),
                    ("d3_um", d),
                    ("ex_um", d),
                    ("ey_um", d),
                    ("ez_um", d),
                    ("flags", Type::Uint32),
                ],
            ),
            batch(
                "PsdBatch",
                &[("x_um", d), ("y_um", d), ("sum_pa", d), ("head_c", d)],
            ),
        ],
        syntax: Some("proto3".into()),
        ..Default::default()
    };
    FileDescriptorSet {
        file: vec![timestamp, raw],
    }
    .encode_to_vec()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(values: SampleValues, k: u64) -> Sample {
        Sample {
            instrument: Instrument::Capball,
            seq: k,
            device_t_us: 1_000 + k * 50,
            host_ns: 1_795_305_600_123_456_789 + k * 50_000,
            fitted_ns: 1_795_305_600_123_000_001 + k * 50_001,
            valid: !k.is_multiple_of(3),
            values,
        }
    }

    #[test]
    fn every_topic_round_trips_exactly() {
        let values = [
            SampleValues::Position {
                raw_nm: -123_456_789,
                position_um: -123.456_789_000_1,
                sig: 87,
                flags: 0x8000_0001,
            },
            SampleValues::Environment {
                air_c: 20.1,
                air_pa: 101_325.0,
                rh_pct: f64::NAN,
                material_c: vec![20.0, 20.5, 19.75],
                n_air: 1.000_271_3,
            },
            SampleValues::Capball {
                volts: [1.0 / 3.0, -2.5, 9.999],
                d_um: [0.1, 0.2, f64::INFINITY],
                e_um: [-0.0, 1e-300, 7.0],
                flags: 5,
            },
            SampleValues::Psd {
                x_um: f64::NAN,
                y_um: 3.25,
                sum_pa: 1e6,
                head_c: 21.0,
            },
        ];
        for v in values {
            let mut first = sample(v.clone(), 0);
            first.instrument = match v {
                SampleValues::Position { .. } | SampleValues::Environment { .. } => {
                    Instrument::Interferometer
                }
                SampleValues::Capball { .. } => Instrument::Capball,
                SampleValues::Psd { .. } => Instrument::Psd,
            };
            let samples: Vec<Sample> = (0..5)
                .map(|k| Sample {
                    instrument: first.instrument,
                    ..sample(v.clone(), k)
                })
                .collect();
            let mut b = Batch::for_sample(&first);
            for s in &samples {
                assert!(b.push(s));
            }
            let mut buf = Vec::new();
            b.encode(&mut buf);
            let back = Batch::decode(b.topic(), &buf).unwrap().unwrap();
            let got = back.samples().unwrap();
            // Bit for bit (NaN != NaN, so compare the debug text of the bits).
            let bits = |xs: &[Sample]| format!("{:?}", xs).replace("NaN", "nan");
            assert_eq!(bits(&got), bits(&samples));
            assert_eq!(got.len(), 5);
        }
    }

    #[test]
    fn mismatched_columns_are_an_error() {
        let b = Batch::Psd(PsdBatch {
            header: Some(BatchHeader {
                seq: vec![1, 2],
                device_t_us: vec![1, 2],
                fitted_time: vec![timestamp(1), timestamp(2)],
                host_time: vec![timestamp(1), timestamp(2)],
                valid: vec![true, true],
            }),
            x_um: vec![1.0],
            ..Default::default()
        });
        assert!(b.samples().unwrap_err().contains("columns"));
    }

    #[test]
    fn the_descriptor_set_names_every_batch_and_its_import() {
        let set = FileDescriptorSet::decode(descriptor_set().as_slice()).unwrap();
        let raw = &set.file[1];
        let names: Vec<_> = raw.message_type.iter().map(|m| m.name()).collect();
        for (_, schema) in RAW_TOPICS {
            assert!(names.contains(&schema.trim_start_matches("metrolog.")));
        }
        assert_eq!(set.file[0].name(), "google/protobuf/timestamp.proto");
    }
}
