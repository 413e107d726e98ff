//! The simulated machine's thermal behaviour (`[thermal]` of a scenario; docs/datasets.md,
//! "Simulated thermal machine"): a lumped heat network of two nodes integrated numerically,
//! written apart from the analysis' model (`thermal` crate: chosen sensors through first-order
//! lags), which it must not share.
//!
//! - the spindle **head** (heat capacity `C_h`) takes the bearings' friction heat
//!   `P = q·(rpm/1000)²` W and loses it to the air (`G_ha`) and to the column (`G_hc`);
//! - the **column** (`C_c`) takes heat from the head and loses it to the air (`G_ca`);
//! - the **air** follows the scenario's ambient temperature.
//!
//! `C_h·dT_h/dt = P − G_ha·(T_h − T_a) − G_hc·(T_h − T_c)` and
//! `C_c·dT_c/dt = G_hc·(T_h − T_c) − G_ca·(T_c − T_a)`, integrated with the classical
//! fourth-order Runge–Kutta method on a fixed step from both nodes at the air's temperature at
//! time 0, tabulated once and interpolated linearly in between.
//!
//! The displacement of the tool against the workpiece at the measuring pose is
//! `a_h·(T_h − T_h(0)) + a_c·(T_c − T_c(0))` (µm, machine frame, `a` in µm/K per axis): the
//! spindle's growth follows its head, the column's bending follows the column. The temperature
//! module reads the sensors at their nodes, plus the spindle speed on one more channel.
//! Times are machine seconds (the scenario's scaled time).

use serde::{Deserialize, Serialize};

use crate::slow::Slow;

/// Where a sensor sits in the heat network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Node {
    Head,
    Column,
    Air,
}

/// A temperature sensor of the simulated module.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalSensor {
    /// Its name in the daemon's `[[temperature.sensors]]`.
    pub name: String,
    /// Where it is, in words.
    pub location: String,
    pub node: Node,
}

/// A change of the spindle speed at machine time `at_s`; the speed holds until the next.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpindleStep {
    pub at_s: f64,
    pub rpm: f64,
}

/// `[thermal]`: the heat network, its heat sources and what the instruments see of it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalMachine {
    /// The air around the machine, °C (machine time).
    pub ambient_c: Slow,
    /// The spindle speed schedule (machine seconds, rpm); 0 rpm before the first step.
    pub spindle: Vec<SpindleStep>,
    /// Friction heat of the bearings, W per (1000 rpm)².
    pub heat_w_per_krpm2: f64,
    /// Heat capacity of the spindle head, J/K.
    pub head_j_per_k: f64,
    /// Heat capacity of the column, J/K.
    pub column_j_per_k: f64,
    /// Conductances, W/K: head–air, head–column, column–air.
    pub head_air_w_per_k: f64,
    pub head_column_w_per_k: f64,
    pub column_air_w_per_k: f64,
    /// Displacement per K of the head's rise, µm/K along machine x, y, z.
    pub head_um_per_k: [f64; 3],
    /// Displacement per K of the column's rise, µm/K along machine x, y, z.
    pub column_um_per_k: [f64; 3],
    /// The module's temperature channels, in register order (the spindle speed follows them).
    pub sensors: Vec<ThermalSensor>,
    /// Integration step, machine seconds.
    #[serde(default = "two_s")]
    pub step_s: f64,
}

fn two_s() -> f64 {
    2.0
}

/// The name of the module's channel that carries the spindle speed (rpm).
pub const SPINDLE_CHANNEL: &str = "spindle_rpm";

impl ThermalMachine {
    /// The spindle speed at machine time `t_s`, rpm.
    pub fn rpm(&self, t_s: f64) -> f64 {
        self.spindle
            .iter()
            .take_while(|s| s.at_s <= t_s)
            .last()
            .map_or(0.0, |s| s.rpm)
    }

    /// Time derivative of (T_h, T_c) at `t_s`.
    fn slope(&self, t_s: f64, th: f64, tc: f64) -> (f64, f64) {
        let ta = self.ambient_c.at(t_s);
        let p = self.heat_w_per_krpm2 * (self.rpm(t_s) / 1000.0).powi(2);
        let flow_hc = self.head_column_w_per_k * (th - tc);
        let dh = (p - self.head_air_w_per_k * (th - ta) - flow_hc) / self.head_j_per_k;
        let dc = (flow_hc - self.column_air_w_per_k * (tc - ta)) / self.column_j_per_k;
        (dh, dc)
    }

    /// What is wrong with the section, if anything.
    pub fn check(&self) -> Result<(), String> {
        let pos = [
            ("head_j_per_k", self.head_j_per_k),
            ("column_j_per_k", self.column_j_per_k),
            ("head_column_w_per_k", self.head_column_w_per_k),
            ("step_s", self.step_s),
        ];
        for (k, v) in pos {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("thermal.{k} must be > 0, got {v}"));
            }
        }
        for (k, v) in [
            ("head_air_w_per_k", self.head_air_w_per_k),
            ("column_air_w_per_k", self.column_air_w_per_k),
            ("heat_w_per_krpm2", self.heat_w_per_krpm2),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("thermal.{k} must be ≥ 0, got {v}"));
            }
        }
        let coeffs = self.head_um_per_k.iter().chain(&self.column_um_per_k);
        if coeffs.into_iter().any(|v| !v.is_finite()) {
            return Err("thermal.head_um_per_k and column_um_per_k must be finite".into());
        }
        if self
            .spindle
            .iter()
            .any(|s| !(s.at_s.is_finite() && s.rpm.is_finite() && s.rpm.abs() <= 30_000.0))
        {
            return Err("thermal.spindle: at_s finite, |rpm| ≤ 30000".into());
        }
        if self.spindle.windows(2).any(|w| w[1].at_s < w[0].at_s) {
            return Err("thermal.spindle: steps must be in time order".into());
        }
        if self.sensors.is_empty() || self.sensors.len() > 100 {
            return Err("thermal.sensors: 1 to 100 sensors".into());
        }
        Ok(())
    }
}

/// The node temperatures at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThermalState {
    pub head_c: f64,
    pub column_c: f64,
    pub air_c: f64,
    pub rpm: f64,
}

/// A [`ThermalMachine`] integrated over `[0, end_s]` machine seconds.
#[derive(Debug, Clone)]
pub struct ThermalTrack {
    pub machine: ThermalMachine,
    /// (T_h, T_c) at `k·step_s`.
    nodes: Vec<(f64, f64)>,
}

impl ThermalTrack {
    /// Integrate from rest (both nodes at the air's temperature at 0) up to `end_s`.
    pub fn new(machine: ThermalMachine, end_s: f64) -> ThermalTrack {
        let h = machine.step_s;
        let steps = (end_s.max(0.0) / h).ceil() as usize + 1;
        let t0 = machine.ambient_c.at(0.0);
        let mut nodes = Vec::with_capacity(steps + 1);
        let (mut th, mut tc) = (t0, t0);
        nodes.push((th, tc));
        for k in 0..steps {
            let t = k as f64 * h;
            let m = &machine;
            let k1 = m.slope(t, th, tc);
            let k2 = m.slope(t + h / 2.0, th + h / 2.0 * k1.0, tc + h / 2.0 * k1.1);
            let k3 = m.slope(t + h / 2.0, th + h / 2.0 * k2.0, tc + h / 2.0 * k2.1);
            let k4 = m.slope(t + h, th + h * k3.0, tc + h * k3.1);
            th += h / 6.0 * (k1.0 + 2.0 * k2.0 + 2.0 * k3.0 + k4.0);
            tc += h / 6.0 * (k1.1 + 2.0 * k2.1 + 2.0 * k3.1 + k4.1);
            nodes.push((th, tc));
        }
        ThermalTrack { machine, nodes }
    }

    /// The state at machine time `t_s` (held at the ends of the integrated span).
    pub fn state(&self, t_s: f64) -> ThermalState {
        let h = self.machine.step_s;
        let last = self.nodes.len() - 1;
        let x = (t_s.max(0.0) / h).min(last as f64);
        let k = (x.floor() as usize).min(last.saturating_sub(1));
        let f = (x - k as f64).clamp(0.0, 1.0);
        let (a, b) = (self.nodes[k], self.nodes[(k + 1).min(last)]);
        ThermalState {
            head_c: a.0 + f * (b.0 - a.0),
            column_c: a.1 + f * (b.1 - a.1),
            air_c: self.machine.ambient_c.at(t_s),
            rpm: self.machine.rpm(t_s),
        }
    }

    /// Tool against workpiece at the measuring pose, machine frame, µm.
    pub fn displacement_um(&self, t_s: f64) -> [f64; 3] {
        let s = self.state(t_s);
        let (h0, c0) = self.nodes[0];
        let m = &self.machine;
        [0, 1, 2].map(|k| {
            m.head_um_per_k[k] * (s.head_c - h0) + m.column_um_per_k[k] * (s.column_c - c0)
        })
    }

    /// The module's channels at `t_s`: each sensor's node temperature (°C), then the spindle
    /// speed (rpm).
    pub fn channels(&self, t_s: f64) -> Vec<Option<f64>> {
        let s = self.state(t_s);
        let mut v: Vec<Option<f64>> = self
            .machine
            .sensors
            .iter()
            .map(|x| {
                Some(match x.node {
                    Node::Head => s.head_c,
                    Node::Column => s.column_c,
                    Node::Air => s.air_c,
                })
            })
            .collect();
        v.push(Some(s.rpm));
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn machine() -> ThermalMachine {
        ThermalMachine {
            ambient_c: Slow::constant(20.0),
            spindle: vec![SpindleStep {
                at_s: 0.0,
                rpm: 4000.0,
            }],
            heat_w_per_krpm2: 3.0,
            head_j_per_k: 15_000.0,
            column_j_per_k: 60_000.0,
            head_air_w_per_k: 6.0,
            head_column_w_per_k: 4.0,
            column_air_w_per_k: 8.0,
            head_um_per_k: [0.0, 0.0, 2.0],
            column_um_per_k: [1.5, 0.0, 0.0],
            sensors: vec![ThermalSensor {
                name: "head".into(),
                location: "spindle head".into(),
                node: Node::Head,
            }],
            step_s: 2.0,
        }
    }

    /// Long after a constant speed starts, the network stands still: the heat balance of
    /// each node, solved here by hand (Cramer's rule), gives its temperature.
    #[test]
    fn steady_state_is_the_heat_balance() {
        let m = machine();
        let p = 3.0 * 16.0;
        // (G_ha + G_hc)·x − G_hc·y = P;  −G_hc·x + (G_hc + G_ca)·y = 0 (rises x, y).
        let (a, b, c, d) = (10.0, -4.0, -4.0, 12.0);
        let det = a * d - b * c;
        let x = p * d / det;
        let y = -c * p / det;
        let t = ThermalTrack::new(m, 200_000.0);
        let s = t.state(200_000.0);
        assert!((s.head_c - 20.0 - x).abs() < 1e-6, "{s:?} vs {x}");
        assert!((s.column_c - 20.0 - y).abs() < 1e-6, "{s:?} vs {y}");
        let d = t.displacement_um(200_000.0);
        assert!((d[0] - 1.5 * y).abs() < 1e-5 && (d[2] - 2.0 * x).abs() < 1e-5);
        assert_eq!(t.channels(10.0)[1], Some(4000.0));
    }

    /// Without the column, the head is a single node: its rise is `P/G·(1 − e^(−t·G/C))`.
    #[test]
    fn one_node_rise_is_exponential() {
        let mut m = machine();
        m.head_column_w_per_k = 1e-12;
        let t = ThermalTrack::new(m, 3000.0);
        for s in [100.0, 1500.0, 3000.0] {
            let want = 48.0 / 6.0 * (1.0 - (-s * 6.0 / 15_000.0f64).exp());
            assert!((t.state(s).head_c - 20.0 - want).abs() < 1e-6, "{s}");
        }
        assert_eq!(t.state(-5.0).head_c, 20.0);
    }
}
