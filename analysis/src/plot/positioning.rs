//! Positioning plots: the ISO 230-2 deviation chart (x̄ ± 2s per direction vs target), the
//! drift-free chart of Stejskal et al. beside it, and one target's deviation vs time; and the
//! residual views of `diagnose`.

use std::path::Path;

use anyhow::{Context as _, anyhow};
use metrology::axis_model::Direction;
use metrology::diagnose::Diagnosis;
use metrology::positioning_data::PositioningData;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::{FONT, ensure_font};
use crate::positioning_report::PositioningAnalysis;

const UP: RGBColor = RGBColor(31, 119, 180);
const DOWN: RGBColor = RGBColor(214, 39, 40);
/// Draws onto an SVG or PNG file by extension.
fn with_backend(
    path: &Path,
    size: (u32, u32),
    draw: &dyn Fn(&DrawingArea<SVGBackend, Shift>) -> anyhow::Result<()>,
    draw_png: &dyn Fn(&DrawingArea<BitMapBackend, Shift>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    ensure_font()?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "svg" => {
            let root = SVGBackend::new(path, size).into_drawing_area();
            draw(&root)?;
            root.present().map_err(|e| anyhow!("{e:?}"))
        }
        "png" => {
            let root = BitMapBackend::new(path, size).into_drawing_area();
            draw_png(&root)?;
            root.present().map_err(|e| anyhow!("{e:?}"))
        }
        _ => anyhow::bail!("plot file must end in .svg or .png: {}", path.display()),
    }
}

fn range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.08).max(0.1);
    (lo - pad, hi + pad)
}

fn e<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("{e:?}")
}

type Band = Vec<(f64, Option<f64>, Option<f64>)>;

/// One chart: per direction a mean line with points and a ±border band (dashed edges).
fn band_chart<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    title: &str,
    series: &[(Direction, Band)],
    y_range: (f64, f64),
    x_range: (f64, f64),
    border_name: &str,
) -> anyhow::Result<()> {
    let mut chart = ChartBuilder::on(area)
        .caption(title, (FONT, 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x_range.0..x_range.1, y_range.0..y_range.1)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("target position / mm")
        .y_desc("deviation / µm")
        .label_style((FONT, 14))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(e)?;
    for (dir, pts) in series {
        let (c, name) = match dir {
            Direction::Up => (UP, "approach +"),
            Direction::Down => (DOWN, "approach −"),
        };
        let mean: Vec<(f64, f64)> = pts
            .iter()
            .filter_map(|(x, m, _)| Some((*x, (*m)?)))
            .collect();
        chart
            .draw_series(LineSeries::new(mean.clone(), c.stroke_width(2)))
            .map_err(e)?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart
            .draw_series(mean.iter().map(|p| Circle::new(*p, 3, c.filled())))
            .map_err(e)?;
        for sign in [1.0, -1.0] {
            let edge: Vec<(f64, f64)> = pts
                .iter()
                .filter_map(|(x, m, b)| Some((*x, (*m)? + sign * (*b)?)))
                .collect();
            let s = chart
                .draw_series(DashedLineSeries::new(
                    edge,
                    6,
                    4,
                    c.mix(0.7).stroke_width(1),
                ))
                .map_err(e)?;
            if sign > 0.0 && *dir == Direction::Up {
                s.label(border_name).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.6).stroke_width(1))
                });
            }
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font((FONT, 14))
        .position(SeriesLabelPosition::UpperLeft)
        .draw()
        .map_err(e)?;
    Ok(())
}

fn draw_positioning_on<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    data: &PositioningData,
    an: &PositioningAnalysis,
    target: usize,
) -> anyhow::Result<()> {
    root.fill(&WHITE).map_err(e)?;
    let (top, bottom) = root.split_vertically(root.dim_in_pixel().1 * 55 / 100);
    let (left, right) = top.split_horizontally(root.dim_in_pixel().0 / 2);
    let iso: Vec<(Direction, Band)> = vec![
        (
            Direction::Up,
            an.targets
                .iter()
                .map(|t| (t.target_mm, t.mean_up_um, t.s_up_um.map(|s| 2.0 * s)))
                .collect(),
        ),
        (
            Direction::Down,
            an.targets
                .iter()
                .map(|t| (t.target_mm, t.mean_down_um, t.s_down_um.map(|s| 2.0 * s)))
                .collect(),
        ),
    ];
    let df: Vec<(Direction, Band)> = an
        .drift_elimination
        .directions
        .iter()
        .map(|d| {
            (
                d.direction,
                d.chart
                    .iter()
                    .map(|p| (p.target_mm, p.deviation_um, p.border_um))
                    .collect(),
            )
        })
        .collect();
    // One y scale for both charts so that the narrowing of the scatter is seen.
    let all = iso.iter().chain(&df).flat_map(|(_, v)| {
        v.iter().flat_map(|(_, m, b)| match (m, b) {
            (Some(m), Some(b)) => vec![m + b, m - b],
            (Some(m), None) => vec![*m],
            _ => vec![],
        })
    });
    let y = range(all);
    let x = range(an.targets.iter().map(|t| t.target_mm));
    band_chart(&left, "ISO 230-2: mean deviation ± 2s", &iso, y, x, "± 2s")?;
    let k = an.drift_elimination.k;
    band_chart(
        &right,
        &format!("drift-free (adjacent differences) ± {k:.2} s_diff"),
        &df,
        y,
        x,
        &format!("± {k:.2} s_diff"),
    )?;

    // Deviation of one target vs time over the cycles.
    let pts = |dir: Direction| -> Vec<(f64, f64)> {
        data.readings
            .iter()
            .filter(|r| r.index == target && r.direction == dir)
            .map(|r| {
                (
                    if data.has_times {
                        r.time_s / 3600.0
                    } else {
                        r.time_s
                    },
                    r.deviation_um,
                )
            })
            .collect()
    };
    let (up, down) = (pts(Direction::Up), pts(Direction::Down));
    let xr = range(up.iter().chain(&down).map(|p| p.0));
    let yr = range(up.iter().chain(&down).map(|p| p.1));
    let x_mm = an
        .targets
        .get(target.wrapping_sub(1))
        .map(|t| t.target_mm)
        .unwrap_or(f64::NAN);
    let mut chart = ChartBuilder::on(&bottom)
        .caption(
            format!("target {target} ({x_mm:.3} mm): deviation vs time over the cycles"),
            (FONT, 20),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc(if data.has_times {
            "time / h"
        } else {
            "reading number (no times in the dataset)"
        })
        .y_desc("deviation / µm")
        .label_style((FONT, 14))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(e)?;
    for (p, c, name) in [(up, UP, "approach +"), (down, DOWN, "approach −")] {
        chart
            .draw_series(LineSeries::new(p.clone(), c.mix(0.5).stroke_width(1)))
            .map_err(e)?
            .label(name)
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, c.filled()));
        chart
            .draw_series(p.iter().map(|q| Circle::new(*q, 3, c.filled())))
            .map_err(e)?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font((FONT, 14))
        .draw()
        .map_err(e)?;
    Ok(())
}

/// Draws the positioning charts to `path` (.svg or .png); `target` (1-based) is the one whose
/// deviation vs time is shown.
pub fn draw_positioning(
    path: &Path,
    data: &PositioningData,
    an: &PositioningAnalysis,
    target: usize,
) -> anyhow::Result<()> {
    with_backend(
        path,
        (1500, 1000),
        &|r| draw_positioning_on(r, data, an, target),
        &|r| draw_positioning_on(r, data, an, target),
    )
    .with_context(|| "drawing the positioning charts".to_string())
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
        .x_desc(ta.desc)
        .y_desc("residual / µm")
        .label_style((FONT, 13))
        .draw()
        .map_err(e)?;
    c.draw_series(data.readings.iter().zip(residuals_um).map(|(r, v)| {
        let col = if r.direction == Direction::Up {
            UP
        } else {
            DOWN
        };
        Circle::new((r.time_s / ta.scale, *v), 2, col.mix(0.6).filled())
    }))
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
        "baseline residuals vs time (line: found effects)",
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
        .x_desc("target position / mm")
        .y_desc("residual / µm")
        .label_style((FONT, 13))
        .draw()
        .map_err(e)?;
    c.draw_series(data.readings.iter().zip(rb).map(|(r, v)| {
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
        .fold(0.0, f64::max)
        * 1.15
        + 1e-3;
    let mut c = ChartBuilder::on(area)
        .caption(
            "RMS residual per target (after the found mean effects)",
            (FONT, 18),
        )
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(55)
        .build_cartesian_2d(0.5f64..(n_t as f64 + 0.5), 0.0..ymax)
        .map_err(e)?;
    c.configure_mesh()
        .x_desc("target index")
        .y_desc("RMS residual / µm")
        .label_style((FONT, 13))
        .draw()
        .map_err(e)?;
    for (k, col) in [(0usize, UP), (1, DOWN)] {
        c.draw_series(sd.iter().enumerate().map(|(i, v)| {
            let x0 = i as f64 + 1.0 + if k == 0 { -0.35 } else { 0.0 };
            Rectangle::new([(x0, 0.0), (x0 + 0.35, v[k])], col.mix(0.7).filled())
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
        "residuals of the extended model (rings: outliers)",
    )?;
    c.draw_series(
        data.readings
            .iter()
            .zip(rf)
            .zip(&d.outlier)
            .filter(|(_, o)| **o)
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
