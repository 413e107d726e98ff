//! From samples and triggers to `/pose` records — the same code live and in replay.
//!
//! [`PoseEngine`] holds one [`SteadyDetector`] per instrument. It is fed every sample and
//! trigger in the order they are written to the log; replay reads the log in file order and
//! feeds the very same calls, so it reproduces the logged pose values bit for bit (JSON
//! numbers are written in shortest round-trip form, so every `f64` reads back exactly).
//!
//! Time axis: samples enter the detector at their clock-fitted time (`Sample::fitted_ns`, the
//! device clock mapped onto the host axis), triggers at their host arrival time — the one
//! axis all instruments and triggers share.

use drivers::{Sample, SampleValues, Trigger};
use metrolog_log::topics::{PoseInstrument, PoseMsg, TriggerEventName};
use metrolog_log::{DetectorSettings, LogError};
use metrology::steady::{SteadyDetector, TriggerKind};

/// The steady-value detectors of the interferometer, the CapBall and the PSD.
#[derive(Debug, Clone)]
pub struct PoseEngine {
    detectors: Vec<(PoseInstrument, SteadyDetector)>,
}

impl PoseEngine {
    pub fn new(settings: &DetectorSettings) -> Result<PoseEngine, LogError> {
        let mk = |i: PoseInstrument, cfg: &metrology::steady::SteadyConfig| {
            SteadyDetector::new(cfg.clone(), i.channels().len()).map(|d| (i, d))
        };
        let mut detectors = Vec::new();
        for (inst, cfg) in [
            (PoseInstrument::Interferometer, &settings.interferometer),
            (PoseInstrument::Capball, &settings.capball),
            (PoseInstrument::Psd, &settings.psd),
        ] {
            if settings.instruments.contains(&inst) {
                detectors.push(mk(inst, cfg)?);
            }
        }
        Ok(PoseEngine { detectors })
    }

    /// Feeds a sample to its instrument's detector (environment records are not).
    pub fn on_sample(&mut self, s: &Sample) -> Vec<PoseMsg> {
        let (inst, values, n): (PoseInstrument, [f64; 3], usize) = match &s.values {
            SampleValues::Position { position_um, .. } => {
                (PoseInstrument::Interferometer, [*position_um, 0.0, 0.0], 1)
            }
            SampleValues::Capball { e_um, .. } => (PoseInstrument::Capball, *e_um, 3),
            SampleValues::Psd { x_um, y_um, .. } => (PoseInstrument::Psd, [*x_um, *y_um, 0.0], 2),
            SampleValues::Environment { .. } => return Vec::new(),
        };
        let Some((_, det)) = self.detectors.iter_mut().find(|(i, _)| *i == inst) else {
            return Vec::new();
        };
        det.push_sample(s.fitted_ns, &values[..n], s.valid)
            .iter()
            .map(|v| PoseMsg::from_value(inst, v))
            .collect()
    }

    /// Feeds a trigger to every detector.
    pub fn on_trigger(&mut self, t: &Trigger) -> Vec<PoseMsg> {
        let kind: TriggerKind = TriggerEventName::from(t.event).into();
        let mut out = Vec::new();
        for (inst, det) in &mut self.detectors {
            for v in det.push_trigger(kind, u32::from(t.pose), t.host_ns) {
                out.push(PoseMsg::from_value(*inst, &v));
            }
        }
        out
    }

    /// End of the run: closes open dwells.
    pub fn finish(&mut self, t_ns: u64) -> Vec<PoseMsg> {
        let mut out = Vec::new();
        for (inst, det) in &mut self.detectors {
            for v in det.finish(t_ns) {
                out.push(PoseMsg::from_value(*inst, &v));
            }
        }
        out
    }
}
