//! Runs measured in blocks (`diagnose/src/axis/blocks.rs`): a trend within the blocks is
//! described in a note, never named as an effect.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use diagnose::axis::{Options, diagnose};
use positioning::axis_model::Direction;
use positioning::positioning_data::{PositioningData, Reading};

/// A run of 4 targets × 2 directions measured in blocks of 6 approaches, normal noise of
/// 1 µm, and a creep of `creep` µm per approach (its sign by direction), or the same
/// readings in the interleaved ISO 230-2 order.
fn run(seed: u64, creep: f64, blocks: bool) -> PositioningData {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut readings = Vec::new();
    for index in 1..=4 {
        for (dir, sign) in [(Direction::Up, -1.0), (Direction::Down, 1.0)] {
            for cycle in 1..=6 {
                let z: f64 = rng.sample(rand_distr::StandardNormal);
                readings.push(Reading {
                    cycle,
                    direction: dir,
                    index,
                    target_mm: 100.0 * index as f64,
                    deviation_um: 3.0 * index as f64 + sign * (2.0 + creep * cycle as f64) + z,
                    time_s: 0.0,
                    air_c: None,
                    material_c: None,
                });
            }
        }
    }
    let key = |r: &Reading| {
        let d = usize::from(r.direction == Direction::Down);
        if blocks {
            (r.index * 2 + d) * 10 + r.cycle
        } else {
            (r.cycle * 2 + d) * 10 + r.index
        }
    };
    readings.sort_by_key(key);
    for (k, r) in readings.iter_mut().enumerate() {
        r.time_s = 60.0 * k as f64;
    }
    PositioningData {
        has_times: true,
        readings,
        ..Default::default()
    }
}

/// Whether the report has the note on a trend within blocks, and the effects it names.
fn report(data: &PositioningData) -> (bool, Vec<String>) {
    let d = diagnose(data, &Options::default()).expect("diagnose");
    let noted = d
        .report
        .notes
        .iter()
        .any(|n| n.contains("within the blocks the readings trend"));
    (
        noted,
        d.report
            .findings
            .into_iter()
            .map(|f| f.effect.name().to_string())
            .collect(),
    )
}

/// A creep of 0.6 σ per approach in blocks is described in 20 of 20 runs and never named
/// as a periodic cause (it repeats with each pair of blocks, 720 s here: with the cycle
/// length taken as for an interleaved run, 18 of the 20 named a cyclic drift near it);
/// noise alone in blocks gets the note at most once in 20 (its level is 10⁻³), and an
/// interleaved run never.
#[test]
fn a_trend_within_blocks_is_described_only_when_there() {
    let creep: Vec<(bool, Vec<String>)> = (0..20).map(|s| report(&run(s, 0.6, true))).collect();
    assert!(creep.iter().all(|r| r.0), "{creep:?}");
    assert!(creep.iter().all(|r| r.1.is_empty()), "{creep:?}");
    let without = (0..20)
        .filter(|s| report(&run(100 + s, 0.0, true)).0)
        .count();
    assert!(without <= 1, "{without}");
    let interleaved = (0..5).filter(|s| report(&run(*s, 0.6, false)).0).count();
    assert_eq!(interleaved, 0);
}
