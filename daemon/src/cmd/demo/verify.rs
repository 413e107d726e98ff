//! The demo's compensate-and-verify loop, as a verification run on a real machine goes: the
//! LinuxCNC table is built from the calibration run's log and written to disk, the simulated
//! axis loads the file as LinuxCNC does (`sim::ScrewComp`, written from LinuxCNC's semantics,
//! not from the table writer), the ISO 230-2 segment of the program runs again through the
//! real drivers, pipeline and log, and both runs are measured against each other
//! (`docs/methods.md`, "Verification run").

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use positioning::compensation::{
    CompensationTable, Dialect, Mode, Options, Remeasured, build, remeasured, verify,
};
use positioning::iso230::AxisStats;
use positioning::positioning_data::PositioningData;
use sim::{Scenario, ScrewComp};

use super::sim_run;
use crate::cmd::input::load_positioning;

/// What the loop produced.
pub struct Loop {
    pub table: CompensationTable,
    /// The files written (comp file first).
    pub files: Vec<PathBuf>,
    /// ISO 230-2 predicted from the calibration run and the table (`compensation::verify`).
    pub predicted: AxisStats,
    /// The calibration run against the verification run, both measured.
    pub remeasured: Remeasured,
    pub verify_log: PathBuf,
}

/// The ISO 230-2 part of a scenario's program: its poses from the first up to the first that
/// leaves the first pose's line along X (another Y, Z, A or C), as the positioning reader of a
/// log finds the run.
pub fn positioning_segment(s: &Scenario) -> Scenario {
    let mut out = s.clone();
    if let Some(first) = s.program.poses.first().copied() {
        let same = |p: &sim::scenario::PoseRow| {
            p.y_mm == first.y_mm
                && p.z_mm == first.z_mm
                && p.a_deg == first.a_deg
                && p.c_deg == first.c_deg
        };
        let n = s.program.poses.iter().take_while(|p| same(p)).count();
        out.program.poses.truncate(n);
    }
    out
}

/// The verification run of `base`: its positioning segment with the same schedule (so the
/// slow effects, compressed by the scenario's `time_scale`, are where they were in the
/// calibration run), new random draws (another seed: the noise of a new measurement) and the
/// table loaded into the axis.
pub fn verification_scenario(base: &Scenario, comp: ScrewComp) -> Scenario {
    let mut s = positioning_segment(base);
    s.seed = base.seed.wrapping_add(1);
    s.axis_comp = Some(comp);
    s
}

/// The LinuxCNC table of `data` (both directions: a `Mean` table leaves the backlash), written
/// into `dir`; the comp file's path first.
pub fn write_linuxcnc_table(
    data: &PositioningData,
    dir: &Path,
) -> anyhow::Result<(CompensationTable, Vec<PathBuf>)> {
    let o = Options {
        dialect: Dialect::LinuxCnc,
        mode: Mode::Bidirectional,
        spacing_mm: None,
        reference_mm: None,
        axis_name: None,
        axis_number: 1,
        point_limit: None,
    };
    let t = build(data, &o)?;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut files = Vec::new();
    for (name, text) in &t.files {
        let p = dir.join(name);
        std::fs::write(&p, text).with_context(|| format!("cannot write {}", p.display()))?;
        files.push(p);
    }
    Ok((t, files))
}

/// Builds the table from the calibration log, writes it into `out/compensation`, runs the
/// verification run in `out/verify` with the simulated axis applying the written comp file,
/// and compares the two runs.
pub async fn compensate_and_verify(calibration_log: &Path, out: &Path) -> anyhow::Result<Loop> {
    let before = load_positioning(calibration_log)?;
    let (table, files) = write_linuxcnc_table(&before, &out.join("compensation"))?;
    let comp = crate::cmd::sim::load_comp_file(&files[0])?;
    let scenario = verification_scenario(&Scenario::demo(), comp);
    println!(
        "\nverification run: the simulated X axis applies {} as LinuxCNC does (motor-pos-cmd = pos-cmd + trim of the direction of motion)",
        files[0].display()
    );
    let dir = out.join("verify");
    let (report, _) = sim_run(scenario, &dir, "metrolog demo, verification run").await?;
    let after = load_positioning(&report.log_path)?;
    Ok(Loop {
        predicted: verify(&before, &table).after,
        remeasured: remeasured(&before, &after),
        table,
        files,
        verify_log: report.log_path,
    })
}
