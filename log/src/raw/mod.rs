//! The raw sample topics as protobuf batches (docs/log-format.md).
//!
//! One MCAP message holds the samples of one instrument topic over at most
//! [`LogOptions::batch_interval`](crate::LogOptions) (10 ms) of host time, column by column.
//! Format 3 (written since issue 10, [`v3`]) keeps every sample's seq, device time, fitted
//! time, host time and validity as a base value plus packed differences, the CB-3 as the ADC
//! codes the wire carried with the calibration that converts them, and the other values as
//! the drivers produced them. Format 2 ([`v2`], one `Timestamp` per sample, the CapBall as
//! nine doubles) is still read. Either way a batch gives back exactly the samples that went
//! in, bit for bit (replay reproduces the logged `/pose` values).
//!
//! The schema of each channel is a `FileDescriptorSet` ([`descriptor_set`]) built here by hand
//! from the same field list as the `prost` messages of [`v3`]; the log crate's tests and the
//! viewers' own protobuf reader (`protobufjs`, in the node check of `daemon/tests`) decode
//! the messages with it.

mod columns;
pub mod v2;
pub mod v3;

use prost::Message;
use prost_types::field_descriptor_proto::{Label, Type};
use prost_types::{DescriptorProto, FieldDescriptorProto, FileDescriptorProto, FileDescriptorSet};
use protocol::convert::CapBallCalibration;
use types::{Sample, SampleValues};

/// Topics of the raw samples (the same names as the JSON topics of older logs).
pub const POSITION_TOPIC: &str = "/interferometer/position";
pub const ENVIRONMENT_TOPIC: &str = "/interferometer/environment";
pub const CAPBALL_TOPIC: &str = "/capball/sample";
pub const PSD_TOPIC: &str = "/psd/sample";
/// The Modbus temperature module's samples (format 3 only: logs of format 2 have none).
pub const TEMPERATURE_TOPIC: &str = "/temperature";

/// The raw topics with their schema (message) names.
pub const RAW_TOPICS: [(&str, &str); 5] = [
    (POSITION_TOPIC, "metrolog.PositionBatch"),
    (ENVIRONMENT_TOPIC, "metrolog.EnvironmentBatch"),
    (CAPBALL_TOPIC, "metrolog.CapballBatch"),
    (PSD_TOPIC, "metrolog.PsdBatch"),
    (TEMPERATURE_TOPIC, "metrolog.TemperatureBatch"),
];

/// The topic of a sample.
pub fn topic_of(s: &Sample) -> &'static str {
    match s.values {
        SampleValues::Position { .. } => POSITION_TOPIC,
        SampleValues::Environment { .. } => ENVIRONMENT_TOPIC,
        SampleValues::Capball { .. } => CAPBALL_TOPIC,
        SampleValues::Psd { .. } => PSD_TOPIC,
        SampleValues::Temperature { .. } => TEMPERATURE_TOPIC,
    }
}

/// The samples of one raw topic waiting to be written as one format-3 message.
#[derive(Debug, Clone, Default)]
pub struct Builder {
    samples: Vec<Sample>,
    /// The CapBall calibration of the run: CB-3 samples it reproduces are stored as codes.
    capball: Option<CapBallCalibration>,
    /// CapBall batches written as codes and as doubles (the calibration did not reproduce
    /// them).
    pub capball_batches: [u64; 2],
}

impl Builder {
    pub fn new(capball: Option<CapBallCalibration>) -> Builder {
        Builder {
            samples: Vec::with_capacity(256),
            capball,
            capball_batches: [0; 2],
        }
    }

    /// Appends `s` (the caller keeps one builder per topic).
    pub fn push(&mut self, s: &Sample) {
        self.samples.push(s.clone());
    }

    pub fn len(&self) -> usize {
        self.samples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The topic of the samples in the builder.
    pub fn topic(&self) -> Option<&'static str> {
        self.samples.first().map(topic_of)
    }

    /// Host arrival time of the first sample (the message's log time).
    pub fn first_host_ns(&self) -> Option<u64> {
        self.samples.first().map(|s| s.host_ns)
    }

    /// The format-3 message of the samples, appended to `buf`; the builder is emptied.
    /// Samples of another topic than the first one's are not part of it (the writer never
    /// mixes them).
    pub fn encode(&mut self, buf: &mut Vec<u8>) {
        let Some(topic) = self.topic() else { return };
        let n = self
            .samples
            .iter()
            .take_while(|s| topic_of(s) == topic)
            .count();
        let samples = &self.samples[..n];
        // Encoding into a Vec cannot fail (it grows).
        let _ = match topic {
            POSITION_TOPIC => v3::PositionBatch::from_samples(samples).encode(buf),
            ENVIRONMENT_TOPIC => v3::EnvironmentBatch::from_samples(samples).encode(buf),
            CAPBALL_TOPIC => {
                let b = v3::CapballBatch::from_samples(samples, self.capball.as_ref());
                self.capball_batches[usize::from(b.calibration.is_none())] += 1;
                b.encode(buf)
            }
            TEMPERATURE_TOPIC => v3::TemperatureBatch::from_samples(samples).encode(buf),
            _ => v3::PsdBatch::from_samples(samples).encode(buf),
        };
        self.samples.clear();
    }
}

/// Why a raw batch does not give its samples back: what is wrong, in which topic's batch,
/// which column and, where it matters, which sample (0-based in the batch).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BatchError {
    /// The message is not a protobuf message of the topic's batch type.
    #[error("{topic} batch does not decode: {source}")]
    Decode {
        topic: &'static str,
        source: prost::DecodeError,
    },
    /// A per-sample column has `len` entries where the batch has `n` samples.
    #[error("{topic} batch: columns of {n} samples, but `{column}` has {len}")]
    ColumnLength {
        topic: &'static str,
        column: &'static str,
        len: usize,
        n: usize,
    },
    /// The per-sample counts of a concatenated column (`material_count` of `material_c`,
    /// `channels` of `values_c`) do not add up to the values stored.
    #[error("{topic} batch: `{counts}` adds up to {total}, `{values}` has {len}")]
    Concatenated {
        topic: &'static str,
        counts: &'static str,
        values: &'static str,
        total: u64,
        len: usize,
    },
    /// A column of bytes (signal strength, flags) holds a larger value.
    #[error("{topic} batch, sample {index}: `{column}` is {value}, above 255")]
    AboveByte {
        topic: &'static str,
        column: &'static str,
        index: usize,
        value: u32,
    },
    /// A timestamp before 1970 or beyond 2554 (not ns since the Unix epoch in a `u64`);
    /// `index` is `None` for the header's base time of format 3.
    #[error(
        "{topic} batch: `{column}`{} is {seconds}.{nanos:09} s, outside the log's range",
        index.map(|i| format!(" of sample {i}")).unwrap_or_default()
    )]
    Timestamp {
        topic: &'static str,
        column: &'static str,
        index: Option<usize>,
        seconds: i64,
        nanos: i32,
    },
    /// A format-3 header of `n` samples without the base time `column`.
    #[error("{topic} batch: the header of {n} samples has no `{column}`")]
    MissingTime {
        topic: &'static str,
        column: &'static str,
        n: usize,
    },
    /// A CB-3 ADC code (a running sum of its difference column) outside 24 bits.
    #[error("{topic} batch, sample {index}: `{column}` gives a CapBall code of {code}, not 24-bit")]
    Code {
        topic: &'static str,
        column: &'static str,
        index: usize,
        code: i64,
    },
    /// A CapBall calibration with other than 9 polynomial coefficients and 16 transform entries.
    #[error(
        "{CAPBALL_TOPIC} batch: a CapBall calibration of {poly} polynomial coefficients and {transform} transform entries (9 and 16 expected)"
    )]
    Calibration { poly: usize, transform: usize },
}

/// A decoded raw batch of either format.
#[derive(Debug, Clone, PartialEq)]
pub enum Batch {
    Format2(v2::Batch),
    Format3(v3::Batch),
}

/// Field 1 of a raw batch: the per-sample header in format 2, never used in format 3. Decoding
/// only this field (prost skips the others without reading them) tells the formats apart.
#[derive(Clone, PartialEq, prost::Message)]
struct FormatProbe {
    #[prost(bytes = "vec", optional, tag = "1")]
    format2_header: Option<Vec<u8>>,
}

impl Batch {
    /// Decodes a message of a raw topic, format 2 or 3; `Ok(None)` for another topic.
    pub fn decode(topic: &str, data: &[u8]) -> Result<Option<Batch>, BatchError> {
        let Some(&(topic, _)) = RAW_TOPICS.iter().find(|(t, _)| *t == topic) else {
            return Ok(None);
        };
        let probe =
            FormatProbe::decode(data).map_err(|source| BatchError::Decode { topic, source })?;
        Ok(if probe.format2_header.is_some() {
            v2::Batch::decode(topic, data)?.map(Batch::Format2)
        } else {
            v3::Batch::decode(topic, data)?.map(Batch::Format3)
        })
    }

    /// Samples in the batch (as its header says; [`Batch::samples`] checks every column).
    pub fn len(&self) -> usize {
        match self {
            Batch::Format2(b) => b.len(),
            Batch::Format3(b) => b.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn topic(&self) -> &'static str {
        match self {
            Batch::Format2(b) => b.topic(),
            Batch::Format3(b) => b.topic(),
        }
    }

    /// The samples back, in order. A batch whose columns differ in length is an error.
    pub fn samples(&self) -> Result<Vec<Sample>, BatchError> {
        match self {
            Batch::Format2(b) => b.samples(),
            Batch::Format3(b) => b.samples(),
        }
    }
}

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

/// A singular (proto3 optional-less) field.
fn single(name: &str, number: i32, ty: Type, type_name: Option<&str>) -> FieldDescriptorProto {
    FieldDescriptorProto {
        label: Some(Label::Optional as i32),
        ..field(name, number, ty, type_name)
    }
}

fn message(name: &str, fields: Vec<FieldDescriptorProto>) -> DescriptorProto {
    DescriptorProto {
        name: Some(name.into()),
        field: fields,
        ..Default::default()
    }
}

/// `header` (tag 2), then repeated value columns from tag 3 on, then `extra` fields as given.
fn batch(
    name: &str,
    columns: &[(&str, Type)],
    extra: Vec<FieldDescriptorProto>,
) -> DescriptorProto {
    let mut fields = vec![single(
        "header",
        2,
        Type::Message,
        Some(".metrolog.SampleHeader"),
    )];
    fields.extend(
        columns
            .iter()
            .enumerate()
            .map(|(i, (n, t))| field(n, i as i32 + 3, *t, None)),
    );
    fields.extend(extra);
    message(name, fields)
}

/// The `FileDescriptorSet` of the raw topics of format 3 (`metrolog/raw.proto` and the
/// `google/protobuf/timestamp.proto` it imports), the schema data of every raw channel. It
/// describes the messages of [`v3`] field for field (a test decodes with it).
pub fn descriptor_set() -> Vec<u8> {
    let timestamp = FileDescriptorProto {
        name: Some("google/protobuf/timestamp.proto".into()),
        package: Some("google.protobuf".into()),
        message_type: vec![message(
            "Timestamp",
            vec![
                single("seconds", 1, Type::Int64, None),
                single("nanos", 2, Type::Int32, None),
            ],
        )],
        syntax: Some("proto3".into()),
        ..Default::default()
    };
    let ts = Some(".google.protobuf.Timestamp");
    let header = message(
        "SampleHeader",
        vec![
            single("count", 1, Type::Uint32, None),
            single("time", 2, Type::Message, ts),
            single("host_time", 3, Type::Message, ts),
            field("seq_delta", 4, Type::Sint64, None),
            field("device_t_us_delta", 5, Type::Sint64, None),
            field("time_delta_ns", 6, Type::Sint64, None),
            field("host_time_delta_ns", 7, Type::Sint64, None),
            field("valid", 8, Type::Bool, None),
        ],
    );
    let calibration = message(
        "CapballCalibration",
        vec![
            field("poly", 1, Type::Double, None),
            field("transform", 2, Type::Double, None),
        ],
    );
    let d = Type::Double;
    let capball_extra = {
        let mut v = vec![
            single(
                "calibration",
                7,
                Type::Message,
                Some(".metrolog.CapballCalibration"),
            ),
            single("mean_ex_um", 8, d, None),
            single("mean_ey_um", 9, d, None),
            single("mean_ez_um", 10, d, None),
        ];
        let doubles = [
            "volts_1", "volts_2", "volts_3", "d1_um", "d2_um", "d3_um", "ex_um", "ey_um", "ez_um",
        ];
        v.extend(
            doubles
                .iter()
                .enumerate()
                .map(|(i, n)| field(n, i as i32 + 11, d, None)),
        );
        v
    };
    let raw = FileDescriptorProto {
        name: Some("metrolog/raw.proto".into()),
        package: Some("metrolog".into()),
        dependency: vec!["google/protobuf/timestamp.proto".into()],
        message_type: vec![
            header,
            calibration,
            batch(
                "PositionBatch",
                &[
                    ("raw_nm_delta", Type::Sint64),
                    ("position_um", d),
                    ("sig", Type::Uint32),
                    ("flags", Type::Uint32),
                ],
                vec![],
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
                vec![],
            ),
            batch(
                "CapballBatch",
                &[
                    ("code_1_delta", Type::Sint32),
                    ("code_2_delta", Type::Sint32),
                    ("code_3_delta", Type::Sint32),
                    ("flags", Type::Uint32),
                ],
                capball_extra,
            ),
            batch(
                "PsdBatch",
                &[("x_um", d), ("y_um", d), ("sum_pa", d), ("head_c", d)],
                vec![],
            ),
            batch(
                "TemperatureBatch",
                &[("values_c", d), ("channels", Type::Uint32)],
                vec![],
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
    use protocol::cb3::code_volts;
    use protocol::convert::{CapBallPoly, CapBallTransform};
    use types::Instrument;

    fn sample(instrument: Instrument, values: SampleValues, k: u64) -> Sample {
        Sample {
            instrument,
            seq: k,
            device_t_us: 1_000 + k * 50,
            host_ns: 1_795_305_600_123_456_789 + k * 50_000,
            fitted_ns: 1_795_305_600_123_000_001 + k * 50_001,
            valid: !k.is_multiple_of(3),
            values,
        }
    }

    /// Bit for bit (NaN != NaN, so compare the debug text, which shows NaN and -0.0).
    fn bits(xs: &[Sample]) -> String {
        format!("{xs:?}")
    }

    fn round_trip(samples: &[Sample], cal: Option<CapBallCalibration>) -> (Vec<u8>, Vec<Sample>) {
        let mut b = Builder::new(cal);
        for s in samples {
            b.push(s);
        }
        let mut buf = Vec::new();
        b.encode(&mut buf);
        assert!(b.is_empty());
        let back = Batch::decode(topic_of(&samples[0]), &buf).unwrap().unwrap();
        assert!(matches!(back, Batch::Format3(_)));
        assert_eq!(back.len(), samples.len());
        (buf, back.samples().unwrap())
    }

    #[test]
    fn every_topic_round_trips_exactly() {
        let values = [
            (
                Instrument::Interferometer,
                SampleValues::Position {
                    raw_nm: -123_456_789,
                    position_um: -123.456_789_000_1,
                    sig: 87,
                    flags: 0x8000_0001,
                },
            ),
            (
                Instrument::Interferometer,
                SampleValues::Environment {
                    air_c: 20.1,
                    air_pa: 101_325.0,
                    rh_pct: f64::NAN,
                    material_c: vec![20.0, 20.5, 19.75],
                    n_air: 1.000_271_3,
                },
            ),
            (
                Instrument::Capball,
                SampleValues::Capball {
                    volts: [1.0 / 3.0, -2.5, 9.999],
                    d_um: [0.1, 0.2, f64::INFINITY],
                    e_um: [-0.0, 1e-300, 7.0],
                    flags: 5,
                },
            ),
            (
                Instrument::Psd,
                SampleValues::Psd {
                    x_um: f64::NAN,
                    y_um: 3.25,
                    sum_pa: 1e6,
                    head_c: 21.0,
                },
            ),
            (
                Instrument::Thermometer,
                SampleValues::Temperature {
                    values_c: vec![20.1, f64::NAN, -5.2, -0.0, 850.0],
                },
            ),
        ];
        for (instrument, v) in values {
            let samples: Vec<Sample> = (0..5).map(|k| sample(instrument, v.clone(), k)).collect();
            let (_, got) = round_trip(&samples, Some(calibration()));
            assert_eq!(bits(&got), bits(&samples));
        }
    }

    /// Header values at the ends of their ranges (differences wrap) come back exactly.
    #[test]
    fn header_extremes_round_trip() {
        let v = SampleValues::Psd {
            x_um: 1.0,
            y_um: 2.0,
            sum_pa: 3.0,
            head_c: 4.0,
        };
        let ends = [0, u64::MAX, 1, u64::MAX / 2 + 7, 1 << 53, 3];
        let samples: Vec<Sample> = ends
            .iter()
            .enumerate()
            .map(|(i, &x)| Sample {
                seq: x,
                device_t_us: u64::MAX - x,
                host_ns: x / 2 + i as u64,
                fitted_ns: x.wrapping_mul(3),
                ..sample(Instrument::Psd, v.clone(), i as u64)
            })
            .collect();
        let (_, got) = round_trip(&samples, None);
        assert_eq!(bits(&got), bits(&samples));
    }

    /// A calibration with non-linear polynomials, a rotation and an offset.
    fn calibration() -> CapBallCalibration {
        CapBallCalibration {
            poly: [
                CapBallPoly {
                    c: [10.1, -0.013, 0.000_7],
                },
                CapBallPoly {
                    c: [9.87, 0.021, -0.000_31],
                },
                CapBallPoly::NOMINAL,
            ],
            transform: CapBallTransform {
                t: [
                    [0.999, -0.035, 0.012, 0.25],
                    [0.034, 1.001, -0.021, -1.5],
                    [-0.011, 0.02, 0.998, 0.003],
                    [0.0, 0.0, 0.0, 1.0],
                ],
            },
        }
    }

    /// CB-3 samples as the driver converts them (`CapBallCalibration::convert`), with codes
    /// at the ends of the 24-bit range and jumps between them.
    fn capball_samples(cal: &CapBallCalibration) -> Vec<Sample> {
        let max = protocol::cb3::CODE_MAX;
        let codes = [
            [0, 0, 0],
            [max, -max - 1, 1],
            [-max - 1, max, -1],
            [max, max, max],
            [-max - 1, -max - 1, -max - 1],
            [123_456, -7_654_321, 42],
            [123_457, -7_654_322, 43],
        ];
        codes
            .iter()
            .enumerate()
            .map(|(k, &c)| {
                let v = cal.convert(c);
                let flags = if c.iter().any(|x| x.abs() >= max) {
                    0b101
                } else {
                    0
                };
                sample(
                    Instrument::Capball,
                    SampleValues::Capball {
                        volts: v.volts,
                        d_um: v.d_um,
                        e_um: v.e_um,
                        flags,
                    },
                    k as u64,
                )
            })
            .collect()
    }

    #[test]
    fn capball_samples_are_stored_as_codes_and_come_back_bit_for_bit() {
        let cal = calibration();
        let samples = capball_samples(&cal);
        let (buf, got) = round_trip(&samples, Some(cal));
        assert_eq!(bits(&got), bits(&samples));
        let Batch::Format3(v3::Batch::Capball(b)) =
            Batch::decode(CAPBALL_TOPIC, &buf).unwrap().unwrap()
        else {
            panic!("not a CapBall batch")
        };
        assert!(b.volts_1.is_empty() && b.ex_um.is_empty(), "doubles stored");
        assert_eq!(b.code_1_delta[..2], [0, protocol::cb3::CODE_MAX]);
        assert_eq!(b.calibration.unwrap().to_calibration().unwrap(), cal);
        // Mean of the valid samples (k = 1, 2, 4, 5), computed here separately.
        let valid: Vec<f64> = samples
            .iter()
            .filter(|s| s.valid)
            .map(|s| match &s.values {
                SampleValues::Capball { e_um, .. } => e_um[0],
                _ => unreachable!(),
            })
            .collect();
        assert_eq!(valid.len(), 4);
        let mean = valid.iter().sum::<f64>() / 4.0;
        assert!((b.mean_ex_um - mean).abs() <= 1e-12 * mean.abs().max(1.0));
        // Codes and calibration are smaller than nine doubles a sample, even for 7 samples.
        let (doubles, _) = round_trip(&samples, None);
        assert!(
            buf.len() < doubles.len(),
            "{} ≥ {}",
            buf.len(),
            doubles.len()
        );
    }

    /// One value the calibration does not reproduce (one ulp off, or volts between two
    /// codes) makes the batch store doubles, still exactly.
    #[test]
    fn capball_samples_the_calibration_does_not_reproduce_are_stored_as_doubles() {
        let cal = calibration();
        for bad in 0..3 {
            let mut samples = capball_samples(&cal);
            if let SampleValues::Capball { volts, e_um, .. } = &mut samples[3].values {
                match bad {
                    0 => e_um[1] = f64::from_bits(e_um[1].to_bits() + 1),
                    1 => volts[0] = (code_volts(5) + code_volts(6)) / 2.0,
                    _ => volts[2] = -0.0,
                }
            }
            let (buf, got) = round_trip(&samples, Some(cal));
            assert_eq!(bits(&got), bits(&samples), "case {bad}");
            let Batch::Format3(v3::Batch::Capball(b)) =
                Batch::decode(CAPBALL_TOPIC, &buf).unwrap().unwrap()
            else {
                panic!()
            };
            assert!(b.calibration.is_none() && b.code_1_delta.is_empty());
            assert_eq!(b.ez_um.len(), samples.len());
        }
        // Without a calibration: doubles as well.
        let samples = capball_samples(&cal);
        let (_, got) = round_trip(&samples, None);
        assert_eq!(bits(&got), bits(&samples));
    }

    #[test]
    fn damaged_batches_are_errors_not_panics() {
        let cal = calibration();
        let samples = capball_samples(&cal);
        let mut b = v3::CapballBatch::from_samples(&samples, Some(&cal));
        b.code_2_delta.pop();
        let e = v3::Batch::Capball(b.clone()).samples().unwrap_err();
        assert!(e.to_string().contains("columns"), "{e}");
        assert_eq!(
            e,
            BatchError::ColumnLength {
                topic: CAPBALL_TOPIC,
                column: "code_2_delta",
                len: 6,
                n: 7
            }
        );
        b.code_2_delta.push(1 << 30);
        let e = v3::Batch::Capball(b.clone()).samples().unwrap_err();
        assert!(e.to_string().contains("24-bit"), "{e}");
        assert!(
            matches!(
                e,
                BatchError::Code {
                    column: "code_2_delta",
                    index: 6,
                    ..
                }
            ),
            "{e:?}"
        );
        b.calibration.as_mut().unwrap().poly.pop();
        let e = v3::Batch::Capball(b).samples().unwrap_err();
        assert!(e.to_string().contains("calibration"), "{e}");
        assert_eq!(
            e,
            BatchError::Calibration {
                poly: 8,
                transform: 16
            }
        );
        let mut p = v3::PsdBatch::from_samples(&samples);
        p.header.as_mut().unwrap().count = 99;
        assert!(v3::Batch::Psd(p).samples().is_err());
    }

    /// Each error names the topic, the column and, for a value, the sample.
    #[test]
    fn errors_say_what_is_wrong_and_where() {
        let s = |k: u64, sig: u8| {
            let v = SampleValues::Position {
                raw_nm: 1,
                position_um: 0.001,
                sig,
                flags: 0,
            };
            sample(Instrument::Interferometer, v, k)
        };
        let mut b = v3::PositionBatch::from_samples(&[s(0, 90), s(1, 91), s(2, 92)]);
        b.sig[2] = 300;
        let e = v3::Batch::Position(b.clone()).samples().unwrap_err();
        assert_eq!(
            e.to_string(),
            "/interferometer/position batch, sample 2: `sig` is 300, above 255"
        );
        b.header.as_mut().unwrap().host_time = None;
        let e = v3::Batch::Position(b.clone()).samples().unwrap_err();
        assert_eq!(
            e.to_string(),
            "/interferometer/position batch: the header of 3 samples has no `host_time`"
        );
        b.header.as_mut().unwrap().time.as_mut().unwrap().seconds = -1;
        let e = v3::Batch::Position(b).samples().unwrap_err();
        assert!(
            matches!(
                e,
                BatchError::Timestamp {
                    column: "time",
                    index: None,
                    seconds: -1,
                    ..
                }
            ),
            "{e:?}"
        );
        let mut h = v2::BatchHeader {
            seq: vec![1, 2],
            device_t_us: vec![1, 2],
            fitted_time: vec![v2::timestamp(1), v2::timestamp(2)],
            host_time: vec![v2::timestamp(1), v2::timestamp(2)],
            valid: vec![true, true],
        };
        h.host_time[1].nanos = 1_000_000_000;
        let m = v2::PsdBatch {
            header: Some(h),
            x_um: vec![1.0; 2],
            y_um: vec![1.0; 2],
            sum_pa: vec![1.0; 2],
            head_c: vec![1.0; 2],
        };
        let e = v2::Batch::Psd(m).samples().unwrap_err();
        assert_eq!(
            e.to_string(),
            "/psd/sample batch: `host_time` of sample 1 is 0.1000000000 s, outside the log's range"
        );
        let v = SampleValues::Environment {
            air_c: 20.0,
            air_pa: 101_325.0,
            rh_pct: 50.0,
            material_c: vec![20.0, 20.5],
            n_air: 1.000_27,
        };
        let mut env =
            v3::EnvironmentBatch::from_samples(&[sample(Instrument::Interferometer, v, 0)]);
        env.material_count[0] = 3;
        let e = v3::Batch::Environment(env).samples().unwrap_err();
        assert_eq!(
            e,
            BatchError::Concatenated {
                topic: ENVIRONMENT_TOPIC,
                counts: "material_count",
                values: "material_c",
                total: 3,
                len: 2
            }
        );
        let e = Batch::decode(PSD_TOPIC, &[0xff]).unwrap_err();
        assert!(
            matches!(
                e,
                BatchError::Decode {
                    topic: PSD_TOPIC,
                    ..
                }
            ),
            "{e:?}"
        );
    }

    /// A format-2 message (header at tag 1) is read as format 2.
    #[test]
    fn format_2_batches_are_told_apart() {
        let h = v2::BatchHeader {
            seq: vec![7],
            device_t_us: vec![8],
            fitted_time: vec![v2::timestamp(9)],
            host_time: vec![v2::timestamp(10)],
            valid: vec![true],
        };
        let m = v2::PsdBatch {
            header: Some(h),
            x_um: vec![1.0],
            y_um: vec![2.0],
            sum_pa: vec![3.0],
            head_c: vec![4.0],
        };
        let b = Batch::decode(PSD_TOPIC, &m.encode_to_vec())
            .unwrap()
            .unwrap();
        assert!(matches!(b, Batch::Format2(_)));
        let s = b.samples().unwrap();
        assert_eq!((s[0].seq, s[0].fitted_ns, s[0].host_ns), (7, 9, 10));
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
