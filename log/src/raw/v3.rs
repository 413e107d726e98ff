//! Format 3 of the raw topics (docs/log-format.md): per-sample header columns as packed
//! differences, the CB-3 as ADC codes plus the calibration that converts them.
//!
//! Difference columns (`*_delta`) hold, per sample, the value minus the previous sample's
//! value (wrapping, so any `u64`/`i64` comes back exactly); the first entry is the value
//! itself, except for the two time columns, whose first entry is 0 and whose base is the
//! `Timestamp` in the header (no integer beyond 2^53 reaches a JavaScript viewer).

use prost_types::Timestamp;
use protocol::cb3::volts_code;
use protocol::convert::{CapBallCalibration, CapBallPoly, CapBallTransform};
use types::{Sample, SampleValues};

use super::columns::{
    self, Col, Header, Values, capball_doubles, check_lengths, col, decoded, samples,
};
use super::v2::{timestamp, timestamp_ns};
use super::{
    BatchError, CAPBALL_TOPIC, ENVIRONMENT_TOPIC, POSITION_TOPIC, PSD_TOPIC, TEMPERATURE_TOPIC,
};

/// Per-sample columns common to every raw batch. Tag 1 of a batch is never used in format 3
/// (it is format 2's header; `raw::Batch::decode` tells the formats apart by it).
#[derive(Clone, PartialEq, prost::Message)]
pub struct SampleHeader {
    /// Samples in the batch.
    #[prost(uint32, tag = "1")]
    pub count: u32,
    /// Fitted time (device time on the host axis) of the first sample.
    #[prost(message, optional, tag = "2")]
    pub time: Option<Timestamp>,
    /// Host arrival time of the first sample.
    #[prost(message, optional, tag = "3")]
    pub host_time: Option<Timestamp>,
    #[prost(sint64, repeated, tag = "4")]
    pub seq_delta: Vec<i64>,
    #[prost(sint64, repeated, tag = "5")]
    pub device_t_us_delta: Vec<i64>,
    /// Fitted time minus the previous sample's, ns (first entry 0: `time`).
    #[prost(sint64, repeated, tag = "6")]
    pub time_delta_ns: Vec<i64>,
    /// Host arrival time minus the previous sample's, ns (first entry 0: `host_time`).
    #[prost(sint64, repeated, tag = "7")]
    pub host_time_delta_ns: Vec<i64>,
    #[prost(bool, repeated, tag = "8")]
    pub valid: Vec<bool>,
}

/// `/interferometer/position`: LI-80 `$POS` records.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PositionBatch {
    #[prost(message, optional, tag = "2")]
    pub header: Option<SampleHeader>,
    #[prost(sint64, repeated, tag = "3")]
    pub raw_nm_delta: Vec<i64>,
    #[prost(double, repeated, tag = "4")]
    pub position_um: Vec<f64>,
    #[prost(uint32, repeated, tag = "5")]
    pub sig: Vec<u32>,
    #[prost(uint32, repeated, tag = "6")]
    pub flags: Vec<u32>,
}

/// `/interferometer/environment`: LI-80 `$ENV` records; `material_c` holds the material
/// temperatures of all samples one after the other, `material_count[i]` of sample `i`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct EnvironmentBatch {
    #[prost(message, optional, tag = "2")]
    pub header: Option<SampleHeader>,
    #[prost(double, repeated, tag = "3")]
    pub air_c: Vec<f64>,
    #[prost(double, repeated, tag = "4")]
    pub air_pa: Vec<f64>,
    #[prost(double, repeated, tag = "5")]
    pub rh_pct: Vec<f64>,
    #[prost(double, repeated, tag = "6")]
    pub n_air: Vec<f64>,
    #[prost(double, repeated, tag = "7")]
    pub material_c: Vec<f64>,
    #[prost(uint32, repeated, tag = "8")]
    pub material_count: Vec<u32>,
}

/// The CapBall calibration of a batch: `poly` = c1, c2, c3 of sensor 1, then 2, then 3;
/// `transform` = the 4×4 matrix row by row (`protocol::convert::CapBallCalibration`).
#[derive(Clone, PartialEq, prost::Message)]
pub struct CapballCalibration {
    #[prost(double, repeated, tag = "1")]
    pub poly: Vec<f64>,
    #[prost(double, repeated, tag = "2")]
    pub transform: Vec<f64>,
}

/// `/capball/sample`: CB-3 samples as the wire carried them — the three 24-bit ADC codes
/// (differences) and the flags — with the calibration that turns them into volts, distances
/// and the machine-frame error (`CapBallCalibration::convert`, the driver's conversion). The
/// batch means of the error are for viewers. When the calibration does not reproduce a
/// sample of the batch bit for bit (no calibration known, or values that did not come from a
/// CB-3 frame), the batch stores the nine doubles of every sample instead of codes and
/// calibration.
#[derive(Clone, PartialEq, prost::Message)]
pub struct CapballBatch {
    #[prost(message, optional, tag = "2")]
    pub header: Option<SampleHeader>,
    #[prost(sint32, repeated, tag = "3")]
    pub code_1_delta: Vec<i32>,
    #[prost(sint32, repeated, tag = "4")]
    pub code_2_delta: Vec<i32>,
    #[prost(sint32, repeated, tag = "5")]
    pub code_3_delta: Vec<i32>,
    #[prost(uint32, repeated, tag = "6")]
    pub flags: Vec<u32>,
    #[prost(message, optional, tag = "7")]
    pub calibration: Option<CapballCalibration>,
    /// Mean machine-frame error of the batch's valid samples, µm (NaN when none is valid).
    #[prost(double, tag = "8")]
    pub mean_ex_um: f64,
    #[prost(double, tag = "9")]
    pub mean_ey_um: f64,
    #[prost(double, tag = "10")]
    pub mean_ez_um: f64,
    #[prost(double, repeated, tag = "11")]
    pub volts_1: Vec<f64>,
    #[prost(double, repeated, tag = "12")]
    pub volts_2: Vec<f64>,
    #[prost(double, repeated, tag = "13")]
    pub volts_3: Vec<f64>,
    #[prost(double, repeated, tag = "14")]
    pub d1_um: Vec<f64>,
    #[prost(double, repeated, tag = "15")]
    pub d2_um: Vec<f64>,
    #[prost(double, repeated, tag = "16")]
    pub d3_um: Vec<f64>,
    #[prost(double, repeated, tag = "17")]
    pub ex_um: Vec<f64>,
    #[prost(double, repeated, tag = "18")]
    pub ey_um: Vec<f64>,
    #[prost(double, repeated, tag = "19")]
    pub ez_um: Vec<f64>,
}

/// `/psd/sample`: PSD-2 samples.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PsdBatch {
    #[prost(message, optional, tag = "2")]
    pub header: Option<SampleHeader>,
    #[prost(double, repeated, tag = "3")]
    pub x_um: Vec<f64>,
    #[prost(double, repeated, tag = "4")]
    pub y_um: Vec<f64>,
    #[prost(double, repeated, tag = "5")]
    pub sum_pa: Vec<f64>,
    #[prost(double, repeated, tag = "6")]
    pub head_c: Vec<f64>,
}

/// `/temperature`: the Modbus temperature module's samples (instruments.md §5), °C per
/// channel in register order (NaN: a sensor fault); `values_c` holds the channels of all
/// samples one after the other, `channels[i]` of sample `i` (the same in a run: the names are
/// in the run metadata, `temperature_sensors`).
#[derive(Clone, PartialEq, prost::Message)]
pub struct TemperatureBatch {
    #[prost(message, optional, tag = "2")]
    pub header: Option<SampleHeader>,
    #[prost(double, repeated, tag = "3")]
    pub values_c: Vec<f64>,
    #[prost(uint32, repeated, tag = "4")]
    pub channels: Vec<u32>,
}

/// `x - prev` as the difference column stores it (wrapping: exact for any value).
#[inline]
fn delta(x: u64, prev: u64) -> i64 {
    x.wrapping_sub(prev) as i64
}

/// A difference column back to its values (`first`: the value before the first entry).
fn undelta(d: &[i64], first: u64) -> Vec<u64> {
    let mut v = first;
    d.iter()
        .map(|&x| {
            v = v.wrapping_add(x as u64);
            v
        })
        .collect()
}

impl SampleHeader {
    fn of(samples: &[Sample]) -> SampleHeader {
        let n = samples.len();
        let first = samples.first();
        let mut h = SampleHeader {
            count: n as u32,
            time: first.map(|s| timestamp(s.fitted_ns)),
            host_time: first.map(|s| timestamp(s.host_ns)),
            seq_delta: Vec::with_capacity(n),
            device_t_us_delta: Vec::with_capacity(n),
            time_delta_ns: Vec::with_capacity(n),
            host_time_delta_ns: Vec::with_capacity(n),
            valid: Vec::with_capacity(n),
        };
        let (mut seq, mut dev) = (0, 0);
        let (mut fit, mut host) = first.map_or((0, 0), |s| (s.fitted_ns, s.host_ns));
        for s in samples {
            h.seq_delta.push(delta(s.seq, seq));
            h.device_t_us_delta.push(delta(s.device_t_us, dev));
            h.time_delta_ns.push(delta(s.fitted_ns, fit));
            h.host_time_delta_ns.push(delta(s.host_ns, host));
            h.valid.push(s.valid);
            (seq, dev, fit, host) = (s.seq, s.device_t_us, s.fitted_ns, s.host_ns);
        }
        h
    }

    fn len(&self) -> usize {
        self.count as usize
    }

    /// Every sample's header, the differences summed.
    fn columns(&self, topic: &'static str) -> Result<Header<'_>, BatchError> {
        let n = self.len();
        let base = |t: &Option<Timestamp>, column: &'static str| match t {
            Some(t) => timestamp_ns(t).ok_or(BatchError::Timestamp {
                topic,
                column,
                index: None,
                seconds: t.seconds,
                nanos: t.nanos,
            }),
            None if n == 0 => Ok(0),
            None => Err(BatchError::MissingTime { topic, column, n }),
        };
        let time = base(&self.time, "time")?;
        let host_time = base(&self.host_time, "host_time")?;
        Ok(Header {
            seq: decoded("seq_delta", undelta(&self.seq_delta, 0)),
            device_t_us: decoded("device_t_us_delta", undelta(&self.device_t_us_delta, 0)),
            fitted_ns: decoded("time_delta_ns", undelta(&self.time_delta_ns, time)),
            host_ns: decoded(
                "host_time_delta_ns",
                undelta(&self.host_time_delta_ns, host_time),
            ),
            valid: col("valid", &self.valid),
        })
    }
}

impl PositionBatch {
    pub fn from_samples(samples: &[Sample]) -> PositionBatch {
        let mut b = PositionBatch {
            header: Some(SampleHeader::of(samples)),
            ..Default::default()
        };
        let mut prev = 0i64;
        for s in samples {
            if let SampleValues::Position {
                raw_nm,
                position_um,
                sig,
                flags,
            } = s.values
            {
                b.raw_nm_delta.push(raw_nm.wrapping_sub(prev));
                prev = raw_nm;
                b.position_um.push(position_um);
                b.sig.push(u32::from(sig));
                b.flags.push(flags);
            }
        }
        b
    }
}

impl EnvironmentBatch {
    pub fn from_samples(samples: &[Sample]) -> EnvironmentBatch {
        let mut b = EnvironmentBatch {
            header: Some(SampleHeader::of(samples)),
            ..Default::default()
        };
        for s in samples {
            if let SampleValues::Environment {
                air_c,
                air_pa,
                rh_pct,
                material_c,
                n_air,
            } = &s.values
            {
                b.air_c.push(*air_c);
                b.air_pa.push(*air_pa);
                b.rh_pct.push(*rh_pct);
                b.n_air.push(*n_air);
                b.material_c.extend_from_slice(material_c);
                b.material_count.push(material_c.len() as u32);
            }
        }
        b
    }
}

impl PsdBatch {
    pub fn from_samples(samples: &[Sample]) -> PsdBatch {
        let mut b = PsdBatch {
            header: Some(SampleHeader::of(samples)),
            ..Default::default()
        };
        for s in samples {
            if let SampleValues::Psd {
                x_um,
                y_um,
                sum_pa,
                head_c,
            } = s.values
            {
                b.x_um.push(x_um);
                b.y_um.push(y_um);
                b.sum_pa.push(sum_pa);
                b.head_c.push(head_c);
            }
        }
        b
    }
}

impl TemperatureBatch {
    pub fn from_samples(samples: &[Sample]) -> TemperatureBatch {
        let mut b = TemperatureBatch {
            header: Some(SampleHeader::of(samples)),
            ..Default::default()
        };
        for s in samples {
            if let SampleValues::Temperature { values_c } = &s.values {
                b.values_c.extend_from_slice(values_c);
                b.channels.push(values_c.len() as u32);
            }
        }
        b
    }
}

impl CapballCalibration {
    pub fn of(c: &CapBallCalibration) -> CapballCalibration {
        CapballCalibration {
            poly: c.poly.iter().flat_map(|p| p.c).collect(),
            transform: c.transform.t.iter().flatten().copied().collect(),
        }
    }

    pub fn to_calibration(&self) -> Result<CapBallCalibration, BatchError> {
        if self.poly.len() != 9 || self.transform.len() != 16 {
            return Err(BatchError::Calibration {
                poly: self.poly.len(),
                transform: self.transform.len(),
            });
        }
        Ok(CapBallCalibration {
            poly: std::array::from_fn(|i| CapBallPoly {
                c: std::array::from_fn(|k| self.poly[3 * i + k]),
            }),
            transform: CapBallTransform {
                t: std::array::from_fn(|r| std::array::from_fn(|k| self.transform[4 * r + k])),
            },
        })
    }
}

/// The codes of a CapBall sample if `cal` reproduces its volts, distances and error bit for
/// bit.
fn reproduced_codes(cal: &CapBallCalibration, s: &Sample) -> Option<[i32; 3]> {
    let SampleValues::Capball {
        volts, d_um, e_um, ..
    } = &s.values
    else {
        return None;
    };
    let codes = [
        volts_code(volts[0])?,
        volts_code(volts[1])?,
        volts_code(volts[2])?,
    ];
    let v = cal.convert(codes);
    let same =
        |a: &[f64; 3], b: &[f64; 3]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
    (same(&v.d_um, d_um) && same(&v.e_um, e_um)).then_some(codes)
}

impl CapballBatch {
    /// The batch of `samples`: as codes when `cal` reproduces every one of them, as doubles
    /// otherwise.
    pub fn from_samples(samples: &[Sample], cal: Option<&CapBallCalibration>) -> CapballBatch {
        let mut b = CapballBatch {
            header: Some(SampleHeader::of(samples)),
            ..Default::default()
        };
        let (mut sum, mut valid) = ([0.0; 3], 0usize);
        for s in samples {
            if let SampleValues::Capball { e_um, flags, .. } = &s.values {
                b.flags.push(u32::from(*flags));
                if s.valid {
                    valid += 1;
                    sum.iter_mut().zip(e_um).for_each(|(a, x)| *a += x);
                }
            }
        }
        let mean = sum.map(|x| x / valid as f64);
        [b.mean_ex_um, b.mean_ey_um, b.mean_ez_um] = mean;
        if let Some(cal) = cal
            && b.push_codes(samples, cal)
        {
            b.calibration = Some(CapballCalibration::of(cal));
            return b;
        }
        for s in samples {
            if let SampleValues::Capball {
                volts, d_um, e_um, ..
            } = &s.values
            {
                let cols = [
                    &mut b.volts_1,
                    &mut b.volts_2,
                    &mut b.volts_3,
                    &mut b.d1_um,
                    &mut b.d2_um,
                    &mut b.d3_um,
                    &mut b.ex_um,
                    &mut b.ey_um,
                    &mut b.ez_um,
                ];
                let vals = volts.iter().chain(d_um).chain(e_um);
                cols.into_iter().zip(vals).for_each(|(c, x)| c.push(*x));
            }
        }
        b
    }

    /// Fills the code columns; false (and the columns empty) when a sample is not reproduced.
    fn push_codes(&mut self, samples: &[Sample], cal: &CapBallCalibration) -> bool {
        let mut prev = [0i32; 3];
        for s in samples {
            let Some(codes) = reproduced_codes(cal, s) else {
                self.code_1_delta.clear();
                self.code_2_delta.clear();
                self.code_3_delta.clear();
                return false;
            };
            // Codes are 24-bit: their differences fit an i32.
            self.code_1_delta.push(codes[0] - prev[0]);
            self.code_2_delta.push(codes[1] - prev[1]);
            self.code_3_delta.push(codes[2] - prev[2]);
            prev = codes;
        }
        true
    }

    /// The nine value columns of the batch's `n` samples: stored as doubles, or converted
    /// from the codes with the batch's calibration (named by the code column they come from).
    fn doubles(&self, n: usize) -> Result<[Col<'_, f64>; 9], BatchError> {
        const CODES: [&str; 3] = ["code_1_delta", "code_2_delta", "code_3_delta"];
        let Some(c) = &self.calibration else {
            let cols = [
                &self.volts_1,
                &self.volts_2,
                &self.volts_3,
                &self.d1_um,
                &self.d2_um,
                &self.d3_um,
                &self.ex_um,
                &self.ey_um,
                &self.ez_um,
            ];
            return Ok(capball_doubles(cols.map(Vec::as_slice)));
        };
        let cal = c.to_calibration()?;
        let codes = [&self.code_1_delta, &self.code_2_delta, &self.code_3_delta];
        let lengths: [_; 3] = std::array::from_fn(|k| (CODES[k], codes[k].len()));
        check_lengths(CAPBALL_TOPIC, n, &lengths)?;
        let mut out: [Vec<f64>; 9] = std::array::from_fn(|_| Vec::with_capacity(n));
        let mut acc = [0i64; 3];
        let deltas = codes[0].iter().zip(codes[1]).zip(codes[2]);
        for (i, ((d1, d2), d3)) in deltas.enumerate() {
            let mut code = [0i32; 3];
            for (k, d) in [d1, d2, d3].into_iter().enumerate() {
                acc[k] += i64::from(*d);
                code[k] = i32::try_from(acc[k])
                    .ok()
                    .filter(|c| (-(1 << 23)..(1 << 23)).contains(c))
                    .ok_or(BatchError::Code {
                        topic: CAPBALL_TOPIC,
                        column: CODES[k],
                        index: i,
                        code: acc[k],
                    })?;
            }
            let v = cal.convert(code);
            let values = v.volts.iter().chain(&v.d_um).chain(&v.e_um);
            out.iter_mut().zip(values).for_each(|(c, x)| c.push(*x));
        }
        // Volts, distance and error of sensor k come from the codes of sensor k.
        Ok(std::array::from_fn(|k| {
            decoded(CODES[k % 3], std::mem::take(&mut out[k]))
        }))
    }
}

/// A decoded format-3 batch of one raw topic (one per message read: the size of the
/// variants does not matter).
#[derive(Debug, Clone, PartialEq)]
#[allow(clippy::large_enum_variant)]
pub enum Batch {
    Position(PositionBatch),
    Environment(EnvironmentBatch),
    Capball(CapballBatch),
    Psd(PsdBatch),
    Temperature(TemperatureBatch),
}

impl Batch {
    /// Decodes a format-3 message of a raw topic; `Ok(None)` for another topic.
    pub fn decode(topic: &str, data: &[u8]) -> Result<Option<Batch>, BatchError> {
        use prost::Message;
        if topic == TEMPERATURE_TOPIC {
            return TemperatureBatch::decode(data)
                .map(|b| Some(Batch::Temperature(b)))
                .map_err(|source| BatchError::Decode {
                    topic: TEMPERATURE_TOPIC,
                    source,
                });
        }
        let variants = (
            Batch::Position,
            Batch::Environment,
            Batch::Capball,
            Batch::Psd,
        );
        columns::decode(topic, data, variants)
    }

    pub fn topic(&self) -> &'static str {
        match self {
            Batch::Position(_) => POSITION_TOPIC,
            Batch::Environment(_) => ENVIRONMENT_TOPIC,
            Batch::Capball(_) => CAPBALL_TOPIC,
            Batch::Psd(_) => PSD_TOPIC,
            Batch::Temperature(_) => TEMPERATURE_TOPIC,
        }
    }

    fn header(&self) -> Option<&SampleHeader> {
        match self {
            Batch::Position(b) => b.header.as_ref(),
            Batch::Environment(b) => b.header.as_ref(),
            Batch::Capball(b) => b.header.as_ref(),
            Batch::Psd(b) => b.header.as_ref(),
            Batch::Temperature(b) => b.header.as_ref(),
        }
    }

    /// Samples in the batch, as its header says.
    pub fn len(&self) -> usize {
        self.header().map_or(0, SampleHeader::len)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The samples back, in order. A batch whose columns differ in length is an error.
    pub fn samples(&self) -> Result<Vec<Sample>, BatchError> {
        let Some(h) = self.header() else {
            return Ok(Vec::new());
        };
        let n = h.len();
        let values = match self {
            Batch::Position(b) => {
                let mut raw = 0i64;
                let raw_nm = b.raw_nm_delta.iter().map(|&d| {
                    raw = raw.wrapping_add(d);
                    raw
                });
                let raw_nm = decoded("raw_nm_delta", raw_nm.collect());
                Values::position(raw_nm, &b.position_um, &b.sig, &b.flags)
            }
            Batch::Environment(b) => Values::environment(
                &b.air_c,
                &b.air_pa,
                &b.rh_pct,
                &b.n_air,
                &b.material_c,
                &b.material_count,
            ),
            Batch::Capball(b) => Values::capball(b.doubles(n)?, &b.flags),
            Batch::Psd(b) => Values::psd(&b.x_um, &b.y_um, &b.sum_pa, &b.head_c),
            Batch::Temperature(b) => Values::temperature(&b.values_c, &b.channels),
        };
        let topic = self.topic();
        samples(topic, n, &h.columns(topic)?, &values)
    }
}
