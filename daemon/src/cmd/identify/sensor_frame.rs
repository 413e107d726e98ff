//! `metrolog identify sensor-frame`: the CapBall sensor-frame calibration `T = M S⁺` from the
//! 5×5×5 cube of programmed moves.

use std::path::PathBuf;

use anyhow::Context;
use geometry::capball;
use nalgebra::Vector3;

use crate::cmd::input::read_csv;

#[derive(Debug, clap::Args)]
pub struct SensorFrameArgs {
    pub data: PathBuf,
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: SensorFrameArgs) -> anyhow::Result<()> {
    let text = read_csv(&a.data)?;
    let mut rdr = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let h = rdr.headers()?.clone();
    let names = ["mx_um", "my_um", "mz_um", "s1_um", "s2_um", "s3_um"];
    let idx: Vec<usize> = names
        .iter()
        .map(|n| {
            h.iter()
                .position(|x| x == *n)
                .ok_or_else(|| anyhow::anyhow!("missing column `{n}` (need {names:?})"))
        })
        .collect::<anyhow::Result<_>>()?;
    let (mut m, mut s) = (Vec::new(), Vec::new());
    for (i, rec) in rdr.records().enumerate() {
        let rec = rec?;
        let v: Vec<f64> = idx
            .iter()
            .map(|&k| rec.get(k).unwrap_or("").parse::<f64>())
            .collect::<Result<_, _>>()
            .with_context(|| format!("row {}: not a number", i + 2))?;
        m.push(Vector3::new(v[0], v[1], v[2]));
        s.push(Vector3::new(v[3], v[4], v[5]));
    }
    let f = capball::calibrate_sensor_frame(&m, &s)?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&f)?);
        return Ok(());
    }
    outln!(
        "sensor frame from {} points (residual RMS {:.3} µm)",
        f.n_points,
        f.residual_rms_um
    )?;
    for row in &f.t {
        outln!(
            "  [{:>10.6} {:>10.6} {:>10.6} {:>10.3}]",
            row[0],
            row[1],
            row[2],
            row[3]
        )?;
    }
    outln!(
        "gains {:.5} {:.5} {:.5} ({:+.2} %, {:+.2} %, {:+.2} %)",
        f.gains[0],
        f.gains[1],
        f.gains[2],
        f.gain_error_pct[0],
        f.gain_error_pct[1],
        f.gain_error_pct[2]
    )?;
    let n = f.non_orthogonality_urad;
    outln!(
        "non-orthogonality (cosines) t1·t2 {:.0} t1·t3 {:.0} t2·t3 {:.0} µrad",
        n[0],
        n[1],
        n[2]
    )?;
    let o = f.offsets_um;
    outln!(
        "offsets {:.3} {:.3} {:.3} µm; last row {:?}",
        o[0],
        o[1],
        o[2],
        f.last_row
    )?;
    Ok(())
}
