//! PSD-2 transimpedance board driver.
//!
//! Session (SCPI, commands without `?` have no answer): `INIT:CONT OFF`, `*OPC?` (everything
//! before its `1` belongs to the old stream), `SYST:ERR?` until the queue is empty, `*IDN?`,
//! `CONF:RATE <hz>`, `SYST:ERR?` (must be `0,…`), `INIT:CONT ON`, `*OPC?`.
//! Data lines become [`SampleValues::Psd`]: position from the photocurrents, the calibrated
//! error map and the head thermal correction applied; a sample whose `x1+x2` or `y1+y2` is
//! below the configured minimum is invalid.

use std::time::Duration;

use protocol::Decoded;
use protocol::psd::{DataLine, Decoder, Line};

use crate::link::{Acq, Device, Handler, Link, SessionError};
use crate::{Instrument, Sample, SampleValues};

#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct Config {
    pub port: String,
    pub baud: u32,
    pub rate_hz: u32,
    /// Below this summed photocurrent (x1+x2 or y1+y2), pA, a sample is invalid.
    pub min_sum_pa: f64,
    /// Calibrated error map, subtracted from the position (none: no correction).
    #[serde(default)]
    pub error_map: Option<ErrorMap>,
    /// Head thermal correction (none: no correction).
    #[serde(default)]
    pub head: Option<HeadCorrection>,
}

/// Half the side of the 10 mm × 10 mm diode, µm (`L/2`).
pub const HALF_SIDE_UM: f64 = 5_000.0;

/// A regular grid of measured position errors `(ex, ey)` in µm, bilinearly interpolated and
/// subtracted from the reading; outside the grid the nearest edge value is used.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct ErrorMap {
    /// Position of grid node (0, 0), µm.
    pub x0_um: f64,
    pub y0_um: f64,
    /// Node spacing, µm (> 0).
    pub step_x_um: f64,
    pub step_y_um: f64,
    pub nx: usize,
    pub ny: usize,
    /// Row-major (`iy * nx + ix`) errors at the nodes, µm.
    pub ex_um: Vec<f64>,
    pub ey_um: Vec<f64>,
}

impl ErrorMap {
    /// Check the shape; the message says what to fix.
    pub fn validate(&self) -> Result<(), String> {
        if self.nx < 2 || self.ny < 2 {
            return Err(format!(
                "PSD error map needs at least 2×2 nodes, has {}×{}",
                self.nx, self.ny
            ));
        }
        if !(self.step_x_um > 0.0 && self.step_y_um > 0.0) {
            return Err("PSD error map steps must be positive".into());
        }
        let n = self.nx * self.ny;
        if self.ex_um.len() != n || self.ey_um.len() != n {
            return Err(format!(
                "PSD error map of {}×{} nodes needs {n} values per axis, has {} and {}",
                self.nx,
                self.ny,
                self.ex_um.len(),
                self.ey_um.len()
            ));
        }
        Ok(())
    }

    /// Bilinear interpolation of the errors at `(x, y)`, µm.
    pub fn error_at(&self, x_um: f64, y_um: f64) -> (f64, f64) {
        let cell = |v: f64, v0: f64, step: f64, n: usize| {
            let u = ((v - v0) / step).clamp(0.0, (n - 1) as f64);
            let i = (u.floor() as usize).min(n - 2);
            (i, u - i as f64)
        };
        let (ix, fx) = cell(x_um, self.x0_um, self.step_x_um, self.nx);
        let (iy, fy) = cell(y_um, self.y0_um, self.step_y_um, self.ny);
        let at = |g: &[f64], i: usize, j: usize| g[j * self.nx + i];
        let bil = |g: &[f64]| {
            at(g, ix, iy) * (1.0 - fx) * (1.0 - fy)
                + at(g, ix + 1, iy) * fx * (1.0 - fy)
                + at(g, ix, iy + 1) * (1.0 - fx) * fy
                + at(g, ix + 1, iy + 1) * fx * fy
        };
        (bil(&self.ex_um), bil(&self.ey_um))
    }
}

/// Which PSD axis reads along the spindle axis, i.e. which reading the head's thermal
/// growth shifts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum PsdAxis {
    X,
    Y,
}

/// Head thermal correction `Δl = l0 · α · (T − T_ref)` (instruments.md §3), subtracted from
/// the reading of `axis`.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
pub struct HeadCorrection {
    pub axis: PsdAxis,
    /// Lever length, mm (193 mm for the PSD-2 head).
    pub l0_mm: f64,
    /// Expansion coefficient, µm/(m·K) (1.7 for invar).
    pub alpha_um_per_m_k: f64,
    pub t_ref_c: f64,
}

impl HeadCorrection {
    /// `Δl` in µm at head temperature `t_c`.
    pub fn delta_um(&self, t_c: f64) -> f64 {
        // l0 [mm] · α [µm/(m·K)] = l0·1e-3 m · α µm/(m·K).
        self.l0_mm * 1e-3 * self.alpha_um_per_m_k * (t_c - self.t_ref_c)
    }
}

impl Config {
    /// Position (µm), total photocurrent (pA), validity of one data line.
    pub fn convert(&self, d: &DataLine) -> (f64, f64, f64, bool) {
        let sx = d.x1_pa as f64 + d.x2_pa as f64;
        let sy = d.y1_pa as f64 + d.y2_pa as f64;
        let valid = sx >= self.min_sum_pa && sy >= self.min_sum_pa && sx > 0.0 && sy > 0.0;
        let (mut x, mut y) = if sx > 0.0 && sy > 0.0 {
            (
                HALF_SIDE_UM * (d.x2_pa as f64 - d.x1_pa as f64) / sx,
                HALF_SIDE_UM * (d.y2_pa as f64 - d.y1_pa as f64) / sy,
            )
        } else {
            (f64::NAN, f64::NAN)
        };
        if valid {
            if let Some(m) = &self.error_map {
                let (ex, ey) = m.error_at(x, y);
                x -= ex;
                y -= ey;
            }
            if let Some(h) = &self.head {
                let dl = h.delta_um(d.head_mc as f64 * 1e-3);
                match h.axis {
                    PsdAxis::X => x -= dl,
                    PsdAxis::Y => y -= dl,
                }
            }
        }
        (x, y, sx + sy, valid)
    }
}

struct Psd {
    cfg: Config,
    acq: Acq,
}

impl Handler for Psd {
    type Dec = Decoder;

    fn on_item(&mut self, item: Decoded<Line>, host_ns: u64) -> Option<String> {
        match item {
            Decoded::Reject(r) => self.acq.reject(r.kind, r.bytes),
            Decoded::Frame(Line::Answer(a)) => {
                self.acq.counters.answers += 1;
                return Some(a);
            }
            Decoded::Frame(Line::Data(d)) => {
                if !self.acq.accepting {
                    return None;
                }
                let (seq, device_t_us, fitted_ns) = self.acq.stamp(d.seq as u64, d.t_us, host_ns);
                let (x_um, y_um, sum_pa, valid) = self.cfg.convert(&d);
                self.acq.emit_sample(Sample {
                    instrument: Instrument::Psd,
                    seq,
                    device_t_us,
                    host_ns,
                    fitted_ns,
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
        None
    }
}

/// `SYST:ERR?` answer code (`0,"No error"` → 0).
fn syst_err_code(a: &str) -> Option<i32> {
    a.split(',').next()?.trim().parse().ok()
}

impl Device for Psd {
    fn acq(&mut self) -> &mut Acq {
        &mut self.acq
    }
    fn baud(&self) -> u32 {
        self.cfg.baud
    }
    fn new_decoder(&self) -> Decoder {
        Decoder::new()
    }
    fn idle_timeout(&self) -> Duration {
        crate::li80::idle_timeout(self.cfg.rate_hz)
    }
    fn stop_line(&self) -> &'static str {
        "INIT:CONT OFF\n"
    }

    async fn setup(&mut self, link: &mut Link<Decoder>) -> Result<String, SessionError> {
        if let Some(m) = &self.cfg.error_map
            && let Err(e) = m.validate()
        {
            return Err(SessionError::Device(e));
        }
        self.acq.set_rate(self.cfg.rate_hz);
        link.send("INIT:CONT OFF\n").await?;
        link.expect(self, "*OPC?\n", |a| a.trim() == "1").await?;
        link.reset_decoder();
        // Empty the error queue of whatever came before us.
        for _ in 0..16 {
            let a = link
                .expect(self, "SYST:ERR?\n", |a| syst_err_code(a).is_some())
                .await?;
            if syst_err_code(&a) == Some(0) {
                break;
            }
        }
        let idn = link
            .expect(self, "*IDN?\n", |a| a.starts_with("PSD-2,"))
            .await?;
        let rate = format!("CONF:RATE {}\n", self.cfg.rate_hz);
        link.send(&rate).await?;
        let err = link.command(self, "SYST:ERR?\n").await?;
        if syst_err_code(&err) != Some(0) {
            return Err(SessionError::Device(format!(
                "port {}: command `{}` failed: SYST:ERR? answered `{}`",
                link.path,
                rate.trim(),
                err.escape_debug()
            )));
        }
        self.acq.accepting = true;
        link.send("INIT:CONT ON\n").await?;
        link.expect(self, "*OPC?\n", |a| a.trim() == "1").await?;
        Ok(idn.trim().to_string())
    }
}

pub fn spawn(
    cfg: Config,
    clock: crate::HostClock,
    tx: crate::EventSender,
    cancel: tokio_util::sync::CancellationToken,
) -> tokio::task::JoinHandle<()> {
    let acq = Acq::new(Instrument::Psd, &cfg.port, 32, 64, clock, tx);
    tokio::spawn(crate::link::run(Psd { cfg, acq }, cancel))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> Config {
        Config {
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
        let (_, _, _, ok) = cfg().convert(&line(1000, 3000, 400, 500, 20_000));
        assert!(!ok);
        let (x, _, _, ok) = cfg().convert(&line(0, 0, 0, 0, 0));
        assert!(!ok && x.is_nan());
    }

    #[test]
    fn error_map_bilinear_and_head_correction_by_hand() {
        let mut c = cfg();
        // 2×2 grid over [0, 1000]²; ex grows with x (0 → 10 µm), ey with y (0 → 4 µm).
        c.error_map = Some(ErrorMap {
            x0_um: 0.0,
            y0_um: 0.0,
            step_x_um: 1000.0,
            step_y_um: 1000.0,
            nx: 2,
            ny: 2,
            ex_um: vec![0.0, 10.0, 0.0, 10.0],
            ey_um: vec![0.0, 0.0, 4.0, 4.0],
        });
        // 193 mm · 1.7 µm/(m·K) · 2 K = 0.6562 µm along y.
        c.head = Some(HeadCorrection {
            axis: PsdAxis::Y,
            l0_mm: 193.0,
            alpha_um_per_m_k: 1.7,
            t_ref_c: 20.0,
        });
        // x = 5000·(2500−1500)/4000 = 1250 → clamped to the edge: ex = 10; y = 5000·(2200−1800)/4000 = 500:
        // ey = 2.
        let (x, y, _, ok) = c.convert(&line(1500, 2500, 1800, 2200, 22_000));
        assert!(ok);
        assert!((x - 1240.0).abs() < 1e-9, "{x}");
        assert!((y - (500.0 - 2.0 - 0.6562)).abs() < 1e-9, "{y}");
        assert_eq!(
            c.error_map.as_ref().unwrap().error_at(250.0, 750.0),
            (2.5, 3.0)
        );
    }

    #[test]
    fn error_map_shape_is_checked() {
        let m = ErrorMap {
            x0_um: 0.0,
            y0_um: 0.0,
            step_x_um: 1.0,
            step_y_um: 1.0,
            nx: 3,
            ny: 2,
            ex_um: vec![0.0; 6],
            ey_um: vec![0.0; 5],
        };
        assert!(m.validate().unwrap_err().contains("needs 6 values"));
    }
}
