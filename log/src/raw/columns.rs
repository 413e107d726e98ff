//! A raw batch's columns to samples, whichever format they came in: each format reader
//! ([`super::v2`], [`super::v3`]) only undoes its own encoding (timestamps, differences, ADC
//! codes) into the per-sample columns below; checking every column against the batch's sample
//! count and assembling the [`Sample`]s is done here, once.

use std::borrow::Cow;

use prost::Message;
use types::{Instrument, Sample, SampleValues};

use super::{BatchError, CAPBALL_TOPIC, ENVIRONMENT_TOPIC, POSITION_TOPIC, PSD_TOPIC};

/// A message of a raw topic as the batch of a format (its four message types and the
/// variants of its `Batch` enum, in the order position, environment, CapBall, PSD); `Ok(None)`
/// for another topic.
pub(super) fn decode<P, E, C, S, B>(
    topic: &str,
    data: &[u8],
    batch: (
        impl FnOnce(P) -> B,
        impl FnOnce(E) -> B,
        impl FnOnce(C) -> B,
        impl FnOnce(S) -> B,
    ),
) -> Result<Option<B>, BatchError>
where
    P: Message + Default,
    E: Message + Default,
    C: Message + Default,
    S: Message + Default,
{
    fn d<M: Message + Default>(topic: &'static str, data: &[u8]) -> Result<M, BatchError> {
        M::decode(data).map_err(|source| BatchError::Decode { topic, source })
    }
    Ok(Some(match topic {
        POSITION_TOPIC => batch.0(d(POSITION_TOPIC, data)?),
        ENVIRONMENT_TOPIC => batch.1(d(ENVIRONMENT_TOPIC, data)?),
        CAPBALL_TOPIC => batch.2(d(CAPBALL_TOPIC, data)?),
        PSD_TOPIC => batch.3(d(PSD_TOPIC, data)?),
        _ => return Ok(None),
    }))
}

/// One column of a batch and its name in the message (named in errors).
pub(super) struct Col<'a, T: Clone> {
    pub name: &'static str,
    pub values: Cow<'a, [T]>,
}

/// A column as the message holds it.
pub(super) fn col<'a, T: Clone>(name: &'static str, values: &'a [T]) -> Col<'a, T> {
    Col {
        name,
        values: Cow::Borrowed(values),
    }
}

/// A column decoded from the message's own (`name`d) column.
pub(super) fn decoded<T: Clone>(name: &'static str, values: Vec<T>) -> Col<'static, T> {
    Col {
        name,
        values: Cow::Owned(values),
    }
}

impl<T: Clone> Col<'_, T> {
    fn len(&self) -> usize {
        self.values.len()
    }
}

/// `Ok` when every `(name, len)` column has `n` entries, else which one does not.
pub(super) fn check_lengths(
    topic: &'static str,
    n: usize,
    columns: &[(&'static str, usize)],
) -> Result<(), BatchError> {
    match columns.iter().find(|(_, len)| *len != n) {
        Some(&(column, len)) => Err(BatchError::ColumnLength {
            topic,
            column,
            len,
            n,
        }),
        None => Ok(()),
    }
}

/// What every sample of a batch has: sequence, device time, fitted and host times (ns since
/// the Unix epoch), validity.
pub(super) struct Header<'a> {
    pub seq: Col<'a, u64>,
    pub device_t_us: Col<'a, u64>,
    pub fitted_ns: Col<'a, u64>,
    pub host_ns: Col<'a, u64>,
    pub valid: Col<'a, bool>,
}

/// The value columns of one raw topic, one entry per sample (the CapBall's volts, distances
/// and errors as nine columns, sensor 1 to 3 each; an environment sample's material
/// temperatures are the next `material_count[i]` entries of `material_c`).
pub(super) enum Values<'a> {
    Position {
        raw_nm: Col<'a, i64>,
        position_um: Col<'a, f64>,
        sig: Col<'a, u32>,
        flags: Col<'a, u32>,
    },
    Environment {
        air_c: Col<'a, f64>,
        air_pa: Col<'a, f64>,
        rh_pct: Col<'a, f64>,
        n_air: Col<'a, f64>,
        material_c: Col<'a, f64>,
        material_count: Col<'a, u32>,
    },
    Capball {
        /// volts 1–3, d 1–3, e x–z.
        doubles: [Col<'a, f64>; 9],
        flags: Col<'a, u32>,
    },
    Psd {
        x_um: Col<'a, f64>,
        y_um: Col<'a, f64>,
        sum_pa: Col<'a, f64>,
        head_c: Col<'a, f64>,
    },
    /// A sample's channels are the next `channels[i]` entries of `values_c`.
    Temperature {
        values_c: Col<'a, f64>,
        channels: Col<'a, u32>,
    },
}

/// The names of the CapBall's nine value columns (both formats).
const CAPBALL_DOUBLES: [&str; 9] = [
    "volts_1", "volts_2", "volts_3", "d1_um", "d2_um", "d3_um", "ex_um", "ey_um", "ez_um",
];

/// The CapBall's nine value columns as the message holds them, in [`CAPBALL_DOUBLES`] order.
pub(super) fn capball_doubles(cols: [&[f64]; 9]) -> [Col<'_, f64>; 9] {
    std::array::from_fn(|k| col(CAPBALL_DOUBLES[k], cols[k]))
}

/// The value columns of each topic, by the names both formats give them (format 3's
/// `raw_nm_delta` and CapBall codes come decoded).
impl<'a> Values<'a> {
    pub(super) fn position(
        raw_nm: Col<'a, i64>,
        position_um: &'a [f64],
        sig: &'a [u32],
        flags: &'a [u32],
    ) -> Self {
        Values::Position {
            raw_nm,
            position_um: col("position_um", position_um),
            sig: col("sig", sig),
            flags: col("flags", flags),
        }
    }

    pub(super) fn environment(
        air_c: &'a [f64],
        air_pa: &'a [f64],
        rh_pct: &'a [f64],
        n_air: &'a [f64],
        material_c: &'a [f64],
        material_count: &'a [u32],
    ) -> Self {
        Values::Environment {
            air_c: col("air_c", air_c),
            air_pa: col("air_pa", air_pa),
            rh_pct: col("rh_pct", rh_pct),
            n_air: col("n_air", n_air),
            material_c: col("material_c", material_c),
            material_count: col("material_count", material_count),
        }
    }

    pub(super) fn capball(doubles: [Col<'a, f64>; 9], flags: &'a [u32]) -> Self {
        Values::Capball {
            doubles,
            flags: col("flags", flags),
        }
    }

    pub(super) fn psd(
        x_um: &'a [f64],
        y_um: &'a [f64],
        sum_pa: &'a [f64],
        head_c: &'a [f64],
    ) -> Self {
        Values::Psd {
            x_um: col("x_um", x_um),
            y_um: col("y_um", y_um),
            sum_pa: col("sum_pa", sum_pa),
            head_c: col("head_c", head_c),
        }
    }

    pub(super) fn temperature(values_c: &'a [f64], channels: &'a [u32]) -> Self {
        Values::Temperature {
            values_c: col("values_c", values_c),
            channels: col("channels", channels),
        }
    }

    /// The concatenated column and its per-sample counts, if the topic has one.
    fn concatenated(&self) -> Option<(&Col<'a, f64>, &Col<'a, u32>)> {
        match self {
            Values::Environment {
                material_c,
                material_count,
                ..
            } => Some((material_c, material_count)),
            Values::Temperature { values_c, channels } => Some((values_c, channels)),
            _ => None,
        }
    }

    /// Name and length of every per-sample column.
    fn lengths(&self) -> Vec<(&'static str, usize)> {
        fn l<T: Clone>(c: &Col<'_, T>) -> (&'static str, usize) {
            (c.name, c.len())
        }
        match self {
            Values::Position {
                raw_nm,
                position_um,
                sig,
                flags,
            } => vec![l(raw_nm), l(position_um), l(sig), l(flags)],
            Values::Environment {
                air_c,
                air_pa,
                rh_pct,
                n_air,
                material_count,
                ..
            } => vec![l(air_c), l(air_pa), l(rh_pct), l(n_air), l(material_count)],
            Values::Capball { doubles, flags } => doubles.iter().map(l).chain([l(flags)]).collect(),
            Values::Psd {
                x_um,
                y_um,
                sum_pa,
                head_c,
            } => vec![l(x_um), l(y_um), l(sum_pa), l(head_c)],
            Values::Temperature { channels, .. } => vec![l(channels)],
        }
    }
}

/// `column[index]` as a byte (the LI-80 signal strength, the CB-3 flags).
fn byte(topic: &'static str, column: &Col<'_, u32>, index: usize) -> Result<u8, BatchError> {
    let value = column.values[index];
    u8::try_from(value).map_err(|_| BatchError::AboveByte {
        topic,
        column: column.name,
        index,
        value,
    })
}

/// The `n` samples of a batch of `topic`, in order. Every column must have `n` entries.
pub(super) fn samples(
    topic: &'static str,
    n: usize,
    h: &Header<'_>,
    values: &Values<'_>,
) -> Result<Vec<Sample>, BatchError> {
    let header = [
        (h.seq.name, h.seq.len()),
        (h.device_t_us.name, h.device_t_us.len()),
        (h.fitted_ns.name, h.fitted_ns.len()),
        (h.host_ns.name, h.host_ns.len()),
        (h.valid.name, h.valid.len()),
    ];
    check_lengths(topic, n, &header)?;
    check_lengths(topic, n, &values.lengths())?;
    if let Some((values, counts)) = values.concatenated() {
        let total: u64 = counts.values.iter().map(|&c| u64::from(c)).sum();
        if total != values.len() as u64 {
            return Err(BatchError::Concatenated {
                topic,
                counts: counts.name,
                values: values.name,
                total,
                len: values.len(),
            });
        }
    }
    let mut out = Vec::with_capacity(n);
    // Entries of the concatenated column taken by the samples before.
    let mut taken = 0usize;
    for i in 0..n {
        let (instrument, v) = match values {
            Values::Position {
                raw_nm,
                position_um,
                sig,
                flags,
            } => (
                Instrument::Interferometer,
                SampleValues::Position {
                    raw_nm: raw_nm.values[i],
                    position_um: position_um.values[i],
                    sig: byte(topic, sig, i)?,
                    flags: flags.values[i],
                },
            ),
            Values::Environment {
                air_c,
                air_pa,
                rh_pct,
                n_air,
                material_c,
                material_count,
            } => {
                let k = material_count.values[i] as usize;
                let m = material_c.values[taken..taken + k].to_vec();
                taken += k;
                (
                    Instrument::Interferometer,
                    SampleValues::Environment {
                        air_c: air_c.values[i],
                        air_pa: air_pa.values[i],
                        rh_pct: rh_pct.values[i],
                        material_c: m,
                        n_air: n_air.values[i],
                    },
                )
            }
            Values::Capball { doubles, flags } => {
                let c = |k: usize| std::array::from_fn(|j| doubles[k + j].values[i]);
                (
                    Instrument::Capball,
                    SampleValues::Capball {
                        volts: c(0),
                        d_um: c(3),
                        e_um: c(6),
                        flags: byte(topic, flags, i)?,
                    },
                )
            }
            Values::Psd {
                x_um,
                y_um,
                sum_pa,
                head_c,
            } => (
                Instrument::Psd,
                SampleValues::Psd {
                    x_um: x_um.values[i],
                    y_um: y_um.values[i],
                    sum_pa: sum_pa.values[i],
                    head_c: head_c.values[i],
                },
            ),
            Values::Temperature { values_c, channels } => {
                let k = channels.values[i] as usize;
                let v = values_c.values[taken..taken + k].to_vec();
                taken += k;
                (
                    Instrument::Thermometer,
                    SampleValues::Temperature { values_c: v },
                )
            }
        };
        out.push(Sample {
            instrument,
            seq: h.seq.values[i],
            device_t_us: h.device_t_us.values[i],
            host_ns: h.host_ns.values[i],
            fitted_ns: h.fitted_ns.values[i],
            valid: h.valid.values[i],
            values: v,
        });
    }
    Ok(out)
}
