//! The positioning charts of `analyze positioning --plot`: the ISO 230-2 deviation chart (every
//! run's readings, the mean deviations x̄↑ x̄↓ with their x̄ ± 2s bands and the results block
//! A, E, R, B, M), the drift-free chart of Stejskal et al. beside one target's deviation vs
//! time. Layout rules in `docs/datasets.md` ("Charts").

use std::path::Path;

use anyhow::Context as _;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use positioning::axis_model::Direction;
use positioning::positioning_data::PositioningData;
use positioning::units::Units;

use super::{FONT, LABELS, Mark, axis_range, e, padded_range, side_column, ticks, with_backend};
use crate::export::num;
use crate::positioning_report::PositioningAnalysis;

pub(crate) const UP: RGBColor = RGBColor(31, 119, 180);
pub(crate) const DOWN: RGBColor = RGBColor(214, 39, 40);
/// Margin of the y range beyond the data and bands, as a share of their span.
const Y_MARGIN: f64 = 0.06;
/// Two charts share one y scale (so that the narrowing of the scatter is seen) only when each
/// chart's own data still fill at least this share of the shared range.
const SHARE_MIN_FILL: f64 = 0.85;

type Chart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

fn colour(d: Direction) -> RGBColor {
    match d {
        Direction::Up => UP,
        Direction::Down => DOWN,
    }
}

fn arrow(d: Direction) -> &'static str {
    match d {
        Direction::Up => "↑",
        Direction::Down => "↓",
    }
}

/// A chart with a frame round the plot area, a light grid and tick labels without "-0".
fn framed<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    caption: &str,
    x: (f64, f64),
    y: (f64, f64),
    x_desc: &str,
    u: &Units,
) -> anyhow::Result<Chart<'a, DB>> {
    let (x, y) = (axis_range(x), axis_range(y));
    let mut chart = ChartBuilder::on(area)
        .caption(u.relabel(caption), (FONT, 19))
        .margin(10)
        .margin_right(4)
        .x_label_area_size(44)
        .y_label_area_size(62)
        .build_cartesian_2d(x.0..x.1, y.0..y.1)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc(u.relabel(x_desc))
        .y_desc(u.relabel("deviation / µm"))
        .x_labels(LABELS)
        .y_labels(LABELS)
        .x_label_formatter(&ticks(x))
        .y_label_formatter(&ticks(y))
        .label_style((FONT, 14))
        .axis_desc_style((FONT, 15))
        .bold_line_style(RGBColor(222, 222, 222))
        .light_line_style(RGBColor(242, 242, 242))
        .draw()
        .map_err(e)?;
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [(x.0, y.0), (x.1, y.1)],
            RGBColor(90, 90, 90).stroke_width(1),
        )))
        .map_err(e)?;
    Ok(chart)
}

/// A line through the points with dots on them.
fn line_with_dots<DB: DrawingBackend>(
    chart: &mut Chart<'_, DB>,
    pts: &[(f64, f64)],
    line: ShapeStyle,
    dot: ShapeStyle,
    r: u32,
) -> anyhow::Result<()> {
    chart
        .draw_series(LineSeries::new(pts.to_vec(), line))
        .map_err(e)?;
    chart
        .draw_series(pts.iter().map(|p| Circle::new(*p, r, dot)))
        .map_err(e)?;
    Ok(())
}

/// The readings of one run (cycle and direction) in target order.
fn run_points(data: &PositioningData, cycle: usize, dir: Direction) -> Vec<(f64, f64)> {
    let mut pts: Vec<(f64, f64)> = data
        .readings
        .iter()
        .filter(|r| r.cycle == cycle && r.direction == dir)
        .map(|r| (r.target_mm, r.deviation_um))
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    pts
}

/// Per direction: (target, x̄, 2s) for the targets that have a mean.
fn iso_means(an: &PositioningAnalysis, dir: Direction) -> Vec<(f64, f64, Option<f64>)> {
    an.targets
        .iter()
        .filter_map(|t| {
            let (m, s) = match dir {
                Direction::Up => (t.mean_up_um, t.s_up_um),
                Direction::Down => (t.mean_down_um, t.s_down_um),
            };
            Some((t.target_mm, m?, s.map(|s| 2.0 * s)))
        })
        .collect()
}

/// Per direction: (target, rebuilt deviation, k·s_diff border) of the drift-free chart.
fn drift_points(an: &PositioningAnalysis, dir: Direction) -> Vec<(f64, f64, Option<f64>)> {
    an.drift_elimination
        .directions
        .iter()
        .filter(|d| d.direction == dir)
        .flat_map(|d| &d.chart)
        .filter_map(|p| Some((p.target_mm, p.deviation_um?, p.border_um)))
        .collect()
}

/// Every value a band chart shows: the centre values and the band edges.
fn band_values(v: &[(f64, f64, Option<f64>)]) -> impl Iterator<Item = f64> + '_ {
    v.iter()
        .flat_map(|(_, m, b)| [Some(*m), b.map(|b| m + b), b.map(|b| m - b)])
        .flatten()
}

/// The dashed band edges x̄ ± b of one direction.
fn band_edges<DB: DrawingBackend>(
    chart: &mut Chart<'_, DB>,
    v: &[(f64, f64, Option<f64>)],
    c: RGBColor,
) -> anyhow::Result<()> {
    for sign in [1.0, -1.0] {
        let edge: Vec<(f64, f64)> = v
            .iter()
            .filter_map(|(x, m, b)| Some((*x, m + sign * (*b)?)))
            .collect();
        chart
            .draw_series(DashedLineSeries::new(edge, 7, 4, c.stroke_width(1)))
            .map_err(e)?;
    }
    Ok(())
}

/// The most runs drawn as lines in one direction: beyond it a chart shows nothing more to the
/// eye, and its file grows with every run (50 000 cycles made a 121 MB SVG in 234 s).
pub const MAX_RUNS_DRAWN: usize = 200;

/// The cycles (1-based) whose runs are drawn: all of them up to [`MAX_RUNS_DRAWN`], else that
/// many spread evenly over the run, first and last included. Means and bands use every cycle.
fn drawn_cycles(n: usize) -> Vec<usize> {
    if n <= MAX_RUNS_DRAWN {
        return (1..=n).collect();
    }
    let mut v: Vec<usize> = (0..MAX_RUNS_DRAWN)
        .map(|i| 1 + i * (n - 1) / (MAX_RUNS_DRAWN - 1))
        .collect();
    v.dedup();
    v
}

/// The ISO 230-2 chart: each run's readings (thin lines), x̄↑ x̄↓ (thick), x̄ ± 2s (dashed),
/// the results block and the legend in the column on the right.
fn iso_chart<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PositioningData,
    an: &PositioningAnalysis,
    x: (f64, f64),
    y: (f64, f64),
) -> anyhow::Result<()> {
    let (plot, side) = area.split_horizontally(area.dim_in_pixel().0 - 300);
    let mut chart = framed(
        &plot,
        "ISO 230-2: positional deviation of every run, mean ± 2s",
        x,
        y,
        "target position / mm",
        &data.units(),
    )?;
    let mut legend = Vec::new();
    for dir in [Direction::Up, Direction::Down] {
        let c = colour(dir);
        for cycle in drawn_cycles(data.n_cycles()) {
            let pts = run_points(data, cycle, dir);
            line_with_dots(
                &mut chart,
                &pts,
                c.mix(0.3).stroke_width(1),
                c.mix(0.75).filled(),
                2,
            )?;
        }
        let means = iso_means(an, dir);
        band_edges(&mut chart, &means, c)?;
        let m: Vec<(f64, f64)> = means.iter().map(|(x, m, _)| (*x, *m)).collect();
        chart
            .draw_series(LineSeries::new(m, c.stroke_width(3)))
            .map_err(e)?;
        let a = arrow(dir);
        let n = data.n_cycles();
        let runs = match drawn_cycles(n).len() {
            d if d < n => format!("runs {a} ({d} of {n} cycles drawn)"),
            _ => format!("runs {a} ({n} cycles)"),
        };
        legend.push((Mark::Run(c), runs));
        legend.push((Mark::Line(c), format!("mean {a}")));
        legend.push((Mark::Dashed(c), format!("mean ± 2s {a}")));
    }
    let block: Vec<(String, String)> = an
        .results_block()
        .into_iter()
        .map(|r| {
            let unit = if r.value == "—" {
                String::new()
            } else {
                data.units().relabel(" µm")
            };
            (
                format!("{}  {}", r.symbol, r.name),
                format!("{}{unit}", r.value),
            )
        })
        .collect();
    side_column(&side, 40, "ISO 230-2:2014 results", &block, &legend)
}

/// The drift-free chart: deviations rebuilt from adjacent-target differences with their
/// ±k·s_diff borders; its block gives k and how much larger the classic scatter is.
fn drift_chart<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    an: &PositioningAnalysis,
    u: &Units,
    x: (f64, f64),
    y: (f64, f64),
) -> anyhow::Result<()> {
    let (plot, side) = area.split_horizontally(area.dim_in_pixel().0 - 235);
    let mut chart = framed(
        &plot,
        "drift-free deviation (adjacent differences)",
        x,
        y,
        "target position / mm",
        u,
    )?;
    let de = &an.drift_elimination;
    let mut legend = Vec::new();
    let mut block = vec![("k".to_string(), num(de.k, 2))];
    for dir in [Direction::Up, Direction::Down] {
        let c = colour(dir);
        let pts = drift_points(an, dir);
        band_edges(&mut chart, &pts, c)?;
        let xy: Vec<(f64, f64)> = pts.iter().map(|(x, m, _)| (*x, *m)).collect();
        line_with_dots(&mut chart, &xy, c.stroke_width(2), c.filled(), 3)?;
        let a = arrow(dir);
        legend.push((Mark::Line(c), format!("drift-free {a}")));
        legend.push((Mark::Dashed(c), format!("± k·s_diff {a}")));
        let ratio = de
            .directions
            .iter()
            .find(|d| d.direction == dir)
            .and_then(|d| d.mean_ratio)
            .filter(|r| r.is_finite());
        block.push((
            format!("s / s_diff {a}"),
            ratio.map(|r| num(r, 2)).unwrap_or_else(|| "—".into()),
        ));
    }
    block.push(("anchor: cycle".into(), de.reference_cycle.to_string()));
    side_column(&side, 40, "drift elimination", &block, &legend)
}

/// One target's readings against time over the cycles.
fn time_chart<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    data: &PositioningData,
    an: &PositioningAnalysis,
    target: usize,
) -> anyhow::Result<()> {
    let scale = if data.has_times { 3600.0 } else { 1.0 };
    let pts = |dir: Direction| -> Vec<(f64, f64)> {
        data.readings
            .iter()
            .filter(|r| r.index == target && r.direction == dir)
            .map(|r| (r.time_s / scale, r.deviation_um))
            .collect()
    };
    let (up, down) = (pts(Direction::Up), pts(Direction::Down));
    let x = padded_range(up.iter().chain(&down).map(|p| p.0), 0.03);
    let y = padded_range(up.iter().chain(&down).map(|p| p.1), Y_MARGIN);
    let x_mm = an
        .targets
        .get(target.wrapping_sub(1))
        .map(|t| num(t.target_mm, 3))
        .unwrap_or_else(|| "?".into());
    let (plot, side) = area.split_horizontally(area.dim_in_pixel().0 - 180);
    let mut chart = framed(
        &plot,
        &format!("target {target} ({x_mm} mm): deviation vs time"),
        x,
        y,
        if data.has_times {
            "time / h"
        } else {
            "reading number (no times in the dataset)"
        },
        &data.units(),
    )?;
    let mut legend = Vec::new();
    for (p, dir) in [(up, Direction::Up), (down, Direction::Down)] {
        let c = colour(dir);
        line_with_dots(&mut chart, &p, c.mix(0.5).stroke_width(1), c.filled(), 3)?;
        legend.push((Mark::Run(c), format!("readings {}", arrow(dir))));
    }
    side_column(&side, 40, "", &[], &legend)
}

/// The share of `outer` that `inner` covers.
fn fill(inner: (f64, f64), outer: (f64, f64)) -> f64 {
    (inner.1 - inner.0) / (outer.1 - outer.0)
}

fn draw_positioning_on<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    data: &PositioningData,
    an: &PositioningAnalysis,
    target: usize,
) -> anyhow::Result<()> {
    root.fill(&WHITE).map_err(e)?;
    let (top, bottom) = root.split_vertically(root.dim_in_pixel().1 * 52 / 100);
    let (left, right) = bottom.split_horizontally(root.dim_in_pixel().0 * 55 / 100);
    let iso_vals: Vec<f64> = [Direction::Up, Direction::Down]
        .into_iter()
        .flat_map(|d| band_values(&iso_means(an, d)).collect::<Vec<_>>())
        .chain(data.readings.iter().map(|r| r.deviation_um))
        .collect();
    let df_vals: Vec<f64> = [Direction::Up, Direction::Down]
        .into_iter()
        .flat_map(|d| band_values(&drift_points(an, d)).collect::<Vec<_>>())
        .collect();
    let y_iso = padded_range(iso_vals.iter().copied(), Y_MARGIN);
    let y_df = padded_range(df_vals.iter().copied(), Y_MARGIN);
    let shared = padded_range(iso_vals.iter().chain(&df_vals).copied(), Y_MARGIN);
    let (y_iso, y_df) = if fill(y_iso, shared).min(fill(y_df, shared)) >= SHARE_MIN_FILL {
        (shared, shared)
    } else {
        (y_iso, y_df)
    };
    let x = padded_range(an.targets.iter().map(|t| t.target_mm), 0.03);
    iso_chart(&top, data, an, x, y_iso)?;
    drift_chart(&left, an, &data.units(), x, y_df)?;
    time_chart(&right, data, an, target)
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
        (1500, 1100),
        &|r| draw_positioning_on(r, data, an, target),
        &|r| draw_positioning_on(r, data, an, target),
    )
    .with_context(|| "drawing the positioning charts".to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn at_most_max_runs_are_drawn_first_and_last_included() {
        assert_eq!(drawn_cycles(5), vec![1, 2, 3, 4, 5]);
        assert_eq!(drawn_cycles(MAX_RUNS_DRAWN).len(), MAX_RUNS_DRAWN);
        for n in [MAX_RUNS_DRAWN + 1, 1000, 50_000] {
            let d = drawn_cycles(n);
            assert_eq!(d.len(), MAX_RUNS_DRAWN, "{n}");
            assert_eq!((d[0], *d.last().unwrap()), (1, n));
            assert!(d.windows(2).all(|w| w[0] < w[1]));
        }
    }
}
