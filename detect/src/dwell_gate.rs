//! The other instruments' values of a pose wait for the interferometer's (docs/design.md,
//! "Values off their target").
//!
//! Only the interferometer has an absolute target per pose. When its value of pose k is
//! `off_target`, the dwell was placed on another pose's samples or the zero was not the datum,
//! and the log cannot tell which: the CapBall's and the PSD's values of pose k came from the
//! same triggers' window, so they are not `ok` either. Each instrument's detector decides on
//! its own and in its own time, so a CapBall or PSD value is held here until the
//! interferometer has decided the same pose, or has moved past its dwell (a later value), or
//! the run ends.

use std::collections::{BTreeMap, VecDeque};

use types::{Instrument, PoseMsg, PoseStatus};

/// How many interferometer verdicts are remembered (a run visits poses in order; the values
/// waiting here are of the last few).
const VERDICTS_KEPT: usize = 64;
/// Most values held: past it the oldest goes unjudged (an interferometer that never decides
/// must not make the others' values pile up for the length of a run).
const WAITING_MAX: usize = 1024;

/// Values waiting for the interferometer's verdict on their pose.
#[derive(Debug, Clone, Default)]
pub(crate) struct DwellGate {
    /// Pose → whether the interferometer's value of it was `off_target`.
    verdicts: BTreeMap<u32, bool>,
    /// Order the verdicts came in, to forget the oldest.
    order: VecDeque<u32>,
    /// Start of the interferometer's newest dwell: a value that ended before it is released.
    passed_ns: u64,
    waiting: VecDeque<PoseMsg>,
}

impl DwellGate {
    /// The values of `out` that may go now, in order, with those released by it.
    pub(crate) fn pass(&mut self, out: Vec<PoseMsg>) -> Vec<PoseMsg> {
        let mut released = Vec::with_capacity(out.len());
        for m in out {
            if m.instrument == Instrument::Interferometer {
                self.decide(&m);
                released.push(m);
            } else {
                self.waiting.push_back(m);
            }
        }
        self.release(false, &mut released);
        released
    }

    /// End of the run: every value still waiting goes, judged if its pose was decided.
    pub(crate) fn flush(&mut self, mut out: Vec<PoseMsg>) -> Vec<PoseMsg> {
        out = self.pass(out);
        self.release(true, &mut out);
        out
    }

    fn decide(&mut self, m: &PoseMsg) {
        if self
            .verdicts
            .insert(m.pose, m.status == PoseStatus::OffTarget)
            .is_none()
        {
            self.order.push_back(m.pose);
        }
        if self.order.len() > VERDICTS_KEPT
            && let Some(old) = self.order.pop_front()
        {
            self.verdicts.remove(&old);
        }
        self.passed_ns = self.passed_ns.max(m.t_first_ns);
    }

    /// Moves the waiting values whose pose is decided (or passed, or all with `all`) to `out`,
    /// in order: a value waits behind an earlier one still waiting.
    fn release(&mut self, all: bool, out: &mut Vec<PoseMsg>) {
        while let Some(m) = self.waiting.front() {
            let verdict = self.verdicts.get(&m.pose).copied();
            let full = self.waiting.len() > WAITING_MAX;
            if !(all || full || verdict.is_some() || m.t_last_ns < self.passed_ns) {
                break;
            }
            let Some(mut m) = self.waiting.pop_front() else {
                break;
            };
            if verdict == Some(true) && m.status == PoseStatus::Ok {
                m.status = PoseStatus::OffTarget;
            }
            out.push(m);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn value(instrument: Instrument, pose: u32, status: PoseStatus) -> PoseMsg {
        let t = u64::from(pose) * 1_000_000_000;
        PoseMsg {
            instrument,
            pose,
            status,
            n: 150,
            mean: Default::default(),
            std: Default::default(),
            t_first_ns: t,
            t_last_ns: t + 500_000_000,
            datum_epoch: 0,
        }
    }

    #[test]
    fn a_value_waits_for_the_interferometers_verdict_on_its_pose() {
        use Instrument::{Capball, Interferometer, Psd};
        use PoseStatus::{DeviceAway, OffTarget, Ok};
        let mut g = DwellGate::default();
        // The CapBall decides pose 1 first: it waits.
        assert!(g.pass(vec![value(Capball, 1, Ok)]).is_empty());
        // The interferometer's pose 1 is right: the CapBall's goes as it was.
        let got = g.pass(vec![value(Interferometer, 1, Ok), value(Psd, 1, Ok)]);
        let st: Vec<_> = got
            .iter()
            .map(|m| (m.instrument, m.pose, m.status))
            .collect();
        assert_eq!(
            st,
            [(Interferometer, 1, Ok), (Capball, 1, Ok), (Psd, 1, Ok)]
        );
        // Pose 2's interferometer value is off its target: the others' ok values are not ok;
        // one that already failed keeps its own status.
        g.pass(vec![value(Capball, 2, Ok), value(Psd, 2, DeviceAway)]);
        let got = g.pass(vec![value(Interferometer, 2, OffTarget)]);
        let st: Vec<_> = got.iter().map(|m| (m.instrument, m.status)).collect();
        assert_eq!(
            st,
            [
                (Interferometer, OffTarget),
                (Capball, OffTarget),
                (Psd, DeviceAway)
            ]
        );
        // Pose 3 never gets an interferometer value, pose 4 does: pose 3's CapBall value goes
        // unjudged once the interferometer is past its dwell.
        assert!(g.pass(vec![value(Capball, 3, Ok)]).is_empty());
        let got = g.pass(vec![value(Interferometer, 4, Ok)]);
        assert_eq!(got.len(), 2);
        assert_eq!((got[1].pose, got[1].status), (3, Ok));
        // The run ends with a value still waiting: it goes.
        assert!(g.pass(vec![value(Psd, 5, Ok)]).is_empty());
        let got = g.flush(Vec::new());
        assert_eq!((got[0].pose, got[0].status), (5, Ok));
    }

    #[test]
    fn the_verdicts_kept_are_bounded() {
        let mut g = DwellGate::default();
        for pose in 0..1000 {
            g.pass(vec![value(
                Instrument::Interferometer,
                pose,
                PoseStatus::Ok,
            )]);
        }
        assert_eq!(g.verdicts.len(), VERDICTS_KEPT);
        assert_eq!(g.order.len(), VERDICTS_KEPT);
        // The interferometer decides nothing more: the others' values do not pile up.
        let mut g = DwellGate::default();
        let mut out = 0;
        for pose in 0..5000 {
            out += g
                .pass(vec![value(Instrument::Capball, pose, PoseStatus::Ok)])
                .len();
        }
        assert_eq!(g.waiting.len(), WAITING_MAX);
        assert_eq!(out, 5000 - WAITING_MAX);
    }
}
