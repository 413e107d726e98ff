//! Format 2 of the raw topics (docs/log-format.md): protobuf batches with one
//! `google.protobuf.Timestamp` per sample and the CapBall as nine doubles per sample. Logs of
//! this format are read, no longer written (format 3, [`super`]).

use prost_types::Timestamp;
use types::Sample;

use super::columns::{self, Col, Header, Values, capball_doubles, col, decoded, samples};
use super::{BatchError, CAPBALL_TOPIC, ENVIRONMENT_TOPIC, POSITION_TOPIC, PSD_TOPIC};

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

/// A `Timestamp` as ns since the Unix epoch; `None` outside `u64` ns (or not normalised).
pub(super) fn timestamp_ns(t: &Timestamp) -> Option<u64> {
    if t.seconds < 0 || !(0..1_000_000_000).contains(&t.nanos) {
        return None;
    }
    (t.seconds as u64)
        .checked_mul(1_000_000_000)
        .and_then(|s| s.checked_add(t.nanos as u64))
}

impl BatchHeader {
    /// The `column` of `topic`'s batch as ns since the Unix epoch.
    fn times(
        topic: &'static str,
        column: &'static str,
        ts: &[Timestamp],
    ) -> Result<Col<'static, u64>, BatchError> {
        let ns = ts
            .iter()
            .enumerate()
            .map(|(i, t)| {
                timestamp_ns(t).ok_or(BatchError::Timestamp {
                    topic,
                    column,
                    index: Some(i),
                    seconds: t.seconds,
                    nanos: t.nanos,
                })
            })
            .collect::<Result<_, _>>()?;
        Ok(decoded(column, ns))
    }

    fn columns(&self, topic: &'static str) -> Result<Header<'_>, BatchError> {
        Ok(Header {
            seq: col("seq", &self.seq),
            device_t_us: col("device_t_us", &self.device_t_us),
            fitted_ns: Self::times(topic, "fitted_time", &self.fitted_time)?,
            host_ns: Self::times(topic, "host_time", &self.host_time)?,
            valid: col("valid", &self.valid),
        })
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
    pub fn decode(topic: &str, data: &[u8]) -> Result<Option<Batch>, BatchError> {
        let variants = (
            Batch::Position,
            Batch::Environment,
            Batch::Capball,
            Batch::Psd,
        );
        columns::decode(topic, data, variants)
    }

    /// The samples back, in order. A batch whose columns differ in length is an error.
    pub fn samples(&self) -> Result<Vec<Sample>, BatchError> {
        let Some(h) = self.header() else {
            return Ok(Vec::new());
        };
        let values = match self {
            Batch::Position(b) => {
                Values::position(col("raw_nm", &b.raw_nm), &b.position_um, &b.sig, &b.flags)
            }
            Batch::Environment(b) => Values::environment(
                &b.air_c,
                &b.air_pa,
                &b.rh_pct,
                &b.n_air,
                &b.material_c,
                &b.material_count,
            ),
            Batch::Capball(b) => {
                let doubles = [
                    &b.volts_1, &b.volts_2, &b.volts_3, &b.d1_um, &b.d2_um, &b.d3_um, &b.ex_um,
                    &b.ey_um, &b.ez_um,
                ];
                Values::capball(capball_doubles(doubles.map(Vec::as_slice)), &b.flags)
            }
            Batch::Psd(b) => Values::psd(&b.x_um, &b.y_um, &b.sum_pa, &b.head_c),
        };
        let topic = self.topic();
        samples(topic, h.seq.len(), &h.columns(topic)?, &values)
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
        let e = b.samples().unwrap_err();
        assert!(e.to_string().contains("columns"), "{e}");
        assert_eq!(
            e,
            BatchError::ColumnLength {
                topic: PSD_TOPIC,
                column: "x_um",
                len: 1,
                n: 2
            }
        );
    }
}
