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

use drivers::{Instrument, Sample, SampleValues, Trigger};
use metrolog_log::topics::PoseMsg;
use metrolog_log::{DetectorSettings, LogError};
use metrology::steady::SteadyDetector;

/// The steady-value detectors of the interferometer, the CapBall and the PSD.
#[derive(Debug, Clone)]
pub struct PoseEngine {
    detectors: Vec<(Instrument, SteadyDetector)>,
}

impl PoseEngine {
    pub fn new(settings: &DetectorSettings) -> Result<PoseEngine, LogError> {
        let mk = |i: Instrument, cfg: &metrology::steady::SteadyConfig| {
            SteadyDetector::new(cfg.clone(), i.detector_channels().len()).map(|d| (i, d))
        };
        let mut detectors = Vec::new();
        for (inst, cfg) in [
            (Instrument::Interferometer, &settings.interferometer),
            (Instrument::Capball, &settings.capball),
            (Instrument::Psd, &settings.psd),
        ] {
            if settings.instruments.contains(&inst) {
                detectors.push(mk(inst, cfg)?);
            }
        }
        Ok(PoseEngine { detectors })
    }

    /// Feeds a sample to its instrument's detector (environment records are not).
    pub fn on_sample(&mut self, s: &Sample) -> Vec<PoseMsg> {
        let (inst, values, n): (Instrument, [f64; 3], usize) = match &s.values {
            SampleValues::Position { position_um, .. } => {
                (Instrument::Interferometer, [*position_um, 0.0, 0.0], 1)
            }
            SampleValues::Capball { e_um, .. } => (Instrument::Capball, *e_um, 3),
            SampleValues::Psd { x_um, y_um, .. } => (Instrument::Psd, [*x_um, *y_um, 0.0], 2),
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
        let kind = t.kind();
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
