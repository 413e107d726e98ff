//! Format 2 of the raw topics (docs/log-format.md): protobuf batches with one
//! `google.protobuf.Timestamp` per sample and the CapBall as nine doubles per sample. Logs of
//! this format are read, no longer written (format 3, [`super`]).

use prost::Message;
use prost_types::Timestamp;
use types::{Instrument, Sample, SampleValues};

use super::{CAPBALL_TOPIC, ENVIRONMENT_TOPIC, POSITION_TOPIC, PSD_TOPIC};

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
pub(super) fn timestamp(ns: u64) -> Timestamp {
    Timestamp {
        seconds: (ns / 1_000_000_000) as i64,
        nanos: (ns % 1_000_000_000) as i32,
    }
}

pub(super) fn timestamp_ns(t: &Timestamp) -> Result<u64, String> {
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

/// A format-2 batch of one raw topic.
#[derive(Debug, Clone, PartialEq)]
pub enum Batch {
    Position(PositionBatch),
    Environment(EnvironmentBatch),
    Capball(CapballBatch),
    Psd(PsdBatch),
}

impl Batch {
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

    /// Decodes a format-2 message of a raw topic; `Ok(None)` for another topic.
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
