//! The residual views of `metrolog diagnose --plot`: baseline residuals against time and
//! position, the RMS residual per target and the residuals of the extended model.

use std::path::Path;

use anyhow::Context as _;
use diagnose::axis::Diagnosis;
use plotters::coord::Shift;
use plotters::prelude::*;
use positioning::axis_model::Direction;
use positioning::positioning_data::{PositioningData, Reading};

use super::positioning::{DOWN, UP};
use super::{FONT, LABELS, axis_range, e, padded_range, ticks, with_backend};

fn range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    padded_range(vals, 0.08)
}

fn heat(v: f64) -> RGBColor {
    // Time as colour: blue (start) to red (end).
    let v = v.clamp(0.0, 1.0);
    RGBColor((40.0 + 200.0 * v) as u8, 60, (230.0 - 200.0 * v) as u8)
}

fn draw_diagnosis_on<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    data: &PositioningData,
    d: &Diagnosis,
) -> anyhow::Result<()> {
    root.fill(&WHITE).map_err(e)?;
    let areas = root.split_evenly((2, 2));
    let ta = TimeAxis::of(data);
    draw_baseline_vs_time(&areas[0], data, d, &ta)?;
    draw_baseline_vs_position(&areas[1], data, d, &ta)?;
    draw_rms_per_target(&areas[2], data, d)?;
    draw_final_residuals(&areas[3], data, d, &ta)
}

/// The time axis of the diagnosis charts: hours when the run has times, else reading numbers.
struct TimeAxis {
    scale: f64,
    desc: &'static str,
    t: Vec<f64>,
    t0: f64,
    t1: f64,
}

impl TimeAxis {
    fn of(data: &PositioningData) -> TimeAxis {
        let scale = if data.has_times { 3600.0 } else { 1.0 };
        let desc = if data.has_times {
            "time / h"
        } else {
            "reading number"
        };
        let t: Vec<f64> = data.readings.iter().map(|r| r.time_s / scale).collect();
        let (t0, t1) = range(t.iter().copied());
        TimeAxis {
            scale,
            desc,
            t,
            t0,
            t1,
        }
    }
}

/// A chart of residuals against time, coloured by direction; returned for more series.
fn residuals_vs_time<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    data: &PositioningData,
    residuals_um: &[f64],
    ta: &TimeAxis,
    caption: &str,
) -> anyhow::Result<
    ChartContext<
        'a,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
> {
    let yr = range(residuals_um.iter().copied());
    let mut c = ChartBuilder::on(area)
        .caption(caption, (FONT, 18))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(55)
        .build_cartesian_2d(ta.t0..ta.t1, yr.0..yr.1)
        .map_err(e)?;
    c.configure_mesh()
        .x_labels(LABELS)
        .y_labels(LABELS)
        .x_label_formatter(&ticks((ta.t0, ta.t1)))
        .y_label_formatter(&ticks(yr))
        .x_desc(ta.desc)
        .y_desc(data.units().relabel("residual / µm"))
        .label_style((FONT, 13))
        .draw()
        .map_err(e)?;
    let finite = |(r, v): &(&Reading, &f64)| r.time_s.is_finite() && v.is_finite();
    c.draw_series(
        data.readings
            .iter()
            .zip(residuals_um)
            .filter(finite)
            .map(|(r, v)| {
                let col = if r.direction == Direction::Up {
                    UP
                } else {
                    DOWN
                };
                Circle::new((r.time_s / ta.scale, *v), 2, col.mix(0.6).filled())
            }),
    )
    .map_err(e)?;
    Ok(c)
}

fn draw_baseline_vs_time<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PositioningData,
    d: &Diagnosis,
    ta: &TimeAxis,
) -> anyhow::Result<()> {
    // 1: baseline residuals vs time, with the fitted common-mode effects.
    let mut c = residuals_vs_time(
        area,
        data,
        &d.baseline_residuals_um,
        ta,
        "baseline residuals vs time (blue ↑, red ↓; line: found effects)",
    )?;
    // The common-mode part of the found effects at the axis middle, centred like the residuals.
    let m = &d.model;
    let mid = m.targets_mm.len() / 2;
    let steps = 400;
    let (ta0, tb) =
        ta.t.iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(*v), b.max(*v))
            });
    let mut curve: Vec<(f64, f64)> = (0..=steps)
        .map(|k| {
            let ts = (ta0 + (tb - ta0) * k as f64 / steps as f64) * ta.scale;
            (
                ts / ta.scale,
                m.deterministic_um(mid, Direction::Up, ts)
                    - m.systematic_up_um.get(mid).copied().unwrap_or(0.0),
            )
        })
        .collect();
    let mean = curve.iter().map(|p| p.1).sum::<f64>() / curve.len() as f64;
    for p in &mut curve {
        p.1 -= mean;
    }
    if !m.effects.is_empty() {
        c.draw_series(LineSeries::new(curve, BLACK.stroke_width(2)))
            .map_err(e)?;
    }

    Ok(())
}

fn draw_baseline_vs_position<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PositioningData,
    d: &Diagnosis,
    ta: &TimeAxis,
) -> anyhow::Result<()> {
    let rb = &d.baseline_residuals_um;
    let yr = range(rb.iter().copied());
    let xr = range(data.readings.iter().map(|r| r.target_mm));
    // 2: residuals against position and time together (colour = time).
    let mut c = ChartBuilder::on(area)
        .caption(
            "baseline residuals vs position (colour: time, blue → red)",
            (FONT, 18),
        )
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(55)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(e)?;
    c.configure_mesh()
        .x_labels(LABELS)
        .y_labels(LABELS)
        .x_label_formatter(&ticks(xr))
        .y_label_formatter(&ticks(yr))
        .x_desc(data.units().relabel("target position / mm"))
        .y_desc(data.units().relabel("residual / µm"))
        .label_style((FONT, 13))
        .draw()
        .map_err(e)?;
    let finite = |(r, v): &(&Reading, &f64)| r.target_mm.is_finite() && v.is_finite();
    c.draw_series(data.readings.iter().zip(rb).filter(finite).map(|(r, v)| {
        Circle::new(
            (r.target_mm, *v),
            2,
            heat((r.time_s / ta.scale - ta.t0) / (ta.t1 - ta.t0)).filled(),
        )
    }))
    .map_err(e)?;

    Ok(())
}

fn draw_rms_per_target<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PositioningData,
    d: &Diagnosis,
) -> anyhow::Result<()> {
    // 3: scatter of the final residuals per target and direction.
    let n_t = data.n_targets();
    let mut s = vec![[0.0f64; 2]; n_t];
    let mut n = vec![[0usize; 2]; n_t];
    for ((r, v), o) in data.readings.iter().zip(&d.residuals_um).zip(&d.outlier) {
        if !o {
            let k = if r.direction == Direction::Up { 0 } else { 1 };
            s[r.index - 1][k] += v * v;
            n[r.index - 1][k] += 1;
        }
    }
    let sd: Vec<[f64; 2]> = s
        .iter()
        .zip(&n)
        .map(|(s, n)| {
            [0, 1].map(|k| {
                if n[k] > 0 {
                    (s[k] / n[k] as f64).sqrt()
                } else {
                    0.0
                }
            })
        })
        .collect();
    let ymax = sd
        .iter()
        .flat_map(|v| v.iter())
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max)
        * 1.15
        + 1e-3;
    let (_, ymax) = axis_range((0.0, ymax));
    let mut c = ChartBuilder::on(area)
        .caption(
            "RMS residual per target (blue ↑, red ↓; after the found mean effects)",
            (FONT, 18),
        )
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(55)
        .build_cartesian_2d(0.5f64..(n_t as f64 + 0.5), 0.0..ymax)
        .map_err(e)?;
    c.configure_mesh()
        .x_labels(LABELS)
        .y_labels(LABELS)
        .x_label_formatter(&ticks((0.5, n_t as f64 + 0.5)))
        .y_label_formatter(&ticks((0.0, ymax)))
        .x_desc("target index")
        .y_desc(data.units().relabel("RMS residual / µm"))
        .label_style((FONT, 13))
        .draw()
        .map_err(e)?;
    for (k, col) in [(0usize, UP), (1, DOWN)] {
        c.draw_series(sd.iter().enumerate().map(|(i, v)| {
            let x0 = i as f64 + 1.0 + if k == 0 { -0.35 } else { 0.0 };
            Rectangle::new(
                [(x0, 0.0), (x0 + 0.35, v[k].min(ymax))],
                col.mix(0.7).filled(),
            )
        }))
        .map_err(e)?;
    }

    Ok(())
}

fn draw_final_residuals<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PositioningData,
    d: &Diagnosis,
    ta: &TimeAxis,
) -> anyhow::Result<()> {
    // 4: final residuals vs time, outliers ringed.
    let rf = &d.residuals_um;
    let mut c = residuals_vs_time(
        area,
        data,
        rf,
        ta,
        "residuals of the extended model (blue ↑, red ↓; rings: outliers)",
    )?;
    c.draw_series(
        data.readings
            .iter()
            .zip(rf)
            .zip(&d.outlier)
            .filter(|((r, v), o)| **o && r.time_s.is_finite() && v.is_finite())
            .map(|((r, v), _)| Circle::new((r.time_s / ta.scale, *v), 7, BLACK.stroke_width(2))),
    )
    .map_err(e)?;
    Ok(())
}

/// Draws the residual views of a diagnosis to `path` (.svg or .png).
pub fn draw_diagnosis(path: &Path, data: &PositioningData, d: &Diagnosis) -> anyhow::Result<()> {
    with_backend(
        path,
        (1500, 1000),
        &|r| draw_diagnosis_on(r, data, d),
        &|r| draw_diagnosis_on(r, data, d),
    )
    .with_context(|| "drawing the diagnosis charts".to_string())
}
