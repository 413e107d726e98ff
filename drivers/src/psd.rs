//! PSD-2 transimpedance board driver.
//!
//! Session (SCPI, commands without `?` have no answer): `INIT:CONT OFF`, `*OPC?` (everything
//! before its `1` belongs to the old stream), `SYST:ERR?` until the queue is empty, `*IDN?`,
//! `CONF:RATE <hz>`, `SYST:ERR?` (must be `0,…`), `INIT:CONT ON`, `*OPC?`.
//! Data lines become [`SampleValues::Psd`]: position from the photocurrents, the calibrated
//! error map and the head thermal correction applied; a sample whose `x1+x2` or `y1+y2` is
//! below the configured minimum is invalid.

use std::time::Duration;

use protocol::convert::{ErrorMap, PsdReading, head_thermal_um, psd_position};
use protocol::psd::{DataLine, Decoder, Line};

use crate::sample_path::{FrameConverter, Reading, SamplePath};
use crate::serial_driver::{SerialDriver, SerialSession, idle_timeout};
use crate::serial_link::Port;
use crate::stamper::SampleStamper;
use crate::{DriverError, Instrument, SampleValues};

/// What the daemon configures for the PSD-2.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct PsdConfig {
    pub port: String,
    pub baud: u32,
    pub rate_hz: u32,
    /// Below this summed photocurrent (x1+x2 or y1+y2), pA, a sample is invalid.
    pub min_sum_pa: f64,
    /// Calibrated error map, its interpolated correction added to the position (none: no
    /// correction). A spot outside the map makes the sample invalid unless the map says
    /// `outside = "clamp"`.
    #[serde(default)]
    pub error_map: Option<ErrorMap>,
    /// Head thermal correction (none: no correction).
    #[serde(default)]
    pub head: Option<HeadCorrection>,
}

/// Which PSD axis reads along the spindle axis, i.e. which reading the head's thermal
/// growth shifts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PsdAxis {
    X,
    Y,
}

/// Head thermal correction `Δl = l0 · α · (T − T_ref)` (instruments.md §3, `l0` = 193 mm,
/// invar), subtracted from the reading of `axis`.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct HeadCorrection {
    pub axis: PsdAxis,
    pub t_ref_c: f64,
}

impl PsdConfig {
    /// Position (µm), total photocurrent of the four electrodes (pA), validity.
    pub fn convert(&self, d: &DataLine) -> (f64, f64, f64, bool) {
        let sum_pa = (d.x1_pa as f64 + d.x2_pa as f64) + (d.y1_pa as f64 + d.y2_pa as f64);
        // Sums are integers: `sum ≥ min` ⇔ `sum ≥ ⌈min⌉`.
        let min = if self.min_sum_pa.is_finite() {
            self.min_sum_pa.max(0.0).ceil() as u64
        } else {
            u64::MAX
        };
        let (mut x, mut y) = match psd_position(d, min) {
            PsdReading::Valid { x_um, y_um } => (x_um, y_um),
            PsdReading::LowIntensity { .. } => return (f64::NAN, f64::NAN, sum_pa, false),
        };
        if let Some(m) = &self.error_map {
            match m.apply(x, y) {
                Ok([cx, cy]) => (x, y) = (cx, cy),
                Err(_) => return (x, y, sum_pa, false),
            }
        }
        if let Some(h) = &self.head {
            let dl = head_thermal_um(d.head_mc, h.t_ref_c);
            match h.axis {
                PsdAxis::X => x -= dl,
                PsdAxis::Y => y -= dl,
            }
        }
        (x, y, sum_pa, true)
    }
}

/// PSD-2 data lines to readings: position, error map, head correction, validity.
struct PsdFrames {
    cfg: PsdConfig,
}

impl FrameConverter for PsdFrames {
    type Decoder = Decoder;

    fn new_decoder(&self) -> Decoder {
        Decoder::new()
    }

    fn convert(&mut self, line: Line, _host_ns: u64, out: &mut impl FnMut(Reading)) {
        match line {
            Line::Answer(a) => out(Reading::Answer(a)),
            Line::Data(d) => {
                let (x_um, y_um, sum_pa, valid) = self.cfg.convert(&d);
                out(Reading::Data {
                    raw_seq: d.seq as u64,
                    raw_t_us: d.t_us,
                    valid,
                    values: SampleValues::Psd {
                        x_um,
                        y_um,
                        sum_pa,
                        head_c: d.head_mc as f64 * 1e-3,
                    },
                });
            }
        }
    }
}

/// `SYST:ERR?` answer code (`0,"No error"` → 0).
fn syst_err_code(a: &str) -> Option<i32> {
    a.split(',').next()?.trim().parse().ok()
}

/// The PSD-2's session: SCPI commands, `*OPC?` and the error queue.
struct PsdDriver {
    baud: u32,
    rate_hz: u32,
}

impl SerialDriver for PsdDriver {
    type Converter = PsdFrames;

    fn baud(&self) -> u32 {
        self.baud
    }
    fn idle_timeout(&self) -> Duration {
        idle_timeout(self.rate_hz)
    }
    async fn stop<P: Port>(
        &self,
        s: &mut SerialSession<'_, PsdFrames, P>,
    ) -> Result<(), DriverError> {
        s.send("INIT:CONT OFF\n").await?;
        s.expect("*OPC?\n", |a| a.trim() == "1").await.map(drop)
    }

    async fn setup<P: Port>(
        &self,
        s: &mut SerialSession<'_, PsdFrames, P>,
    ) -> Result<String, DriverError> {
        if let Some(m) = &s.path.converter.cfg.error_map
            && let Err(cause) = m.validate()
        {
            return Err(DriverError::BadErrorMap {
                port: s.port().to_string(),
                cause,
            });
        }
        s.path.stamper.set_rate(self.rate_hz);
        s.send("INIT:CONT OFF\n").await?;
        s.expect("*OPC?\n", |a| a.trim() == "1").await?;
        s.reset_decoder();
        // Empty the error queue of whatever came before us.
        for _ in 0..16 {
            let a = s
                .expect("SYST:ERR?\n", |a| syst_err_code(a).is_some())
                .await?;
            if syst_err_code(&a) == Some(0) {
                break;
            }
        }
        let idn = s.expect("*IDN?\n", |a| a.starts_with("PSD-2,")).await?;
        let rate = format!("CONF:RATE {}\n", self.rate_hz);
        s.send(&rate).await?;
        let err = s.command("SYST:ERR?\n").await?;
        if syst_err_code(&err) != Some(0) {
            return Err(DriverError::CommandFailed {
                port: s.port().to_string(),
                command: rate.trim().to_string(),
                answer: err,
            });
        }
        s.start_accepting();
        s.send("INIT:CONT ON\n").await?;
        s.expect("*OPC?\n", |a| a.trim() == "1").await?;
        Ok(idn.trim().to_string())
    }
}

/// Start the PSD-2 driver task. It runs until `cancel` fires, reconnecting with backoff.
pub fn spawn_psd(
    cfg: PsdConfig,
    clock: crate::HostClock,
    tx: crate::EventSender,
    cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    let driver = PsdDriver {
        baud: cfg.baud,
        rate_hz: cfg.rate_hz,
    };
    let port = cfg.port.clone();
    let path = SamplePath::new(
        PsdFrames { cfg },
        SampleStamper::new(32, 64),
        Instrument::Psd,
        &port,
        clock,
        tx,
    );
    crate::serial_driver::spawn(driver, path, cancel)
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::convert::OutsideMap;

    fn cfg() -> PsdConfig {
        PsdConfig {
            port: String::new(),
            baud: 921_600,
            rate_hz: 100,
            min_sum_pa: 1000.0,
            error_map: None,
            head: None,
        }
    }

    fn line(x1: u64, x2: u64, y1: u64, y2: u64, head_mc: i32) -> DataLine {
        DataLine {
            seq: 0,
            t_us: 0,
            x1_pa: x1,
            x2_pa: x2,
            y1_pa: y1,
            y2_pa: y2,
            head_mc,
        }
    }

    #[test]
    fn position_gating_by_hand() {
        // x = 5000 µm · (3000 − 1000) / 4000 = 2500 µm; y = 5000 · (−2000)/4000 = −2500 µm.
        let (x, y, sum, ok) = cfg().convert(&line(1000, 3000, 3000, 1000, 20_000));
        assert_eq!((x, y, sum, ok), (2500.0, -2500.0, 8000.0, true));
        // y pair below 1000 pA: blocked beam, invalid.
        assert!(!cfg().convert(&line(1000, 3000, 400, 500, 20_000)).3);
        // A fractional minimum: 999.5 pA lets a sum of 1000 pA pass, 999 not.
        let mut c = cfg();
        c.min_sum_pa = 999.5;
        assert!(c.convert(&line(500, 500, 500, 500, 0)).3);
        assert!(!c.convert(&line(499, 500, 500, 500, 0)).3);
        let (x, _, _, ok) = cfg().convert(&line(0, 0, 0, 0, 0));
        assert!(!ok && x.is_nan());
    }

    #[test]
    fn error_map_and_head_correction_by_hand() {
        let mut c = cfg();
        // 2×2 grid over [0, 1000]²: dx grows with x (0 → 10 µm), dy with y (0 → 4 µm).
        c.error_map = Some(ErrorMap {
            x0_um: 0.0,
            y0_um: 0.0,
            dx_um: 1000.0,
            dy_um: 1000.0,
            nx: 2,
            ny: 2,
            corrections_um: vec![[0.0, 0.0], [10.0, 0.0], [0.0, 4.0], [10.0, 4.0]],
            outside: OutsideMap::Error,
        });
        // 193 mm · 1.7 µm/(m·K) · 2 K = 0.6562 µm, subtracted along y.
        c.head = Some(HeadCorrection {
            axis: PsdAxis::Y,
            t_ref_c: 20.0,
        });
        // x = 5000·(2200−1800)/4000 = 500 → +5; y = 5000·(2300−1700)/4000 = 750 → +3 − 0.6562.
        let (x, y, _, ok) = c.convert(&line(1800, 2200, 1700, 2300, 22_000));
        assert!(ok);
        assert!((x - 505.0).abs() < 1e-9, "{x}");
        assert!((y - (753.0 - 0.6562)).abs() < 1e-9, "{y}");
        // x = 1250 µm lies outside the map: invalid.
        assert!(!c.convert(&line(1500, 2500, 1800, 2200, 22_000)).3);
    }
}
