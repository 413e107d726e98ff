//! The Monte Carlo output distribution (histogram, as a probability density) beside the GUM
//! normal density, one panel per output; SVG or PNG by the file extension.

use std::path::Path;

use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use uncertainty::{GumResult, McResult};

use super::{FONT, LABELS, Mark, axis_range, e, side_column, ticks, with_backend};
use crate::export::num;

const MC: RGBColor = RGBColor(31, 119, 180);
const GUM: RGBColor = RGBColor(214, 39, 40);

/// Writes the plot to `path` (`.svg` or `.png`).
pub fn write(
    path: &Path,
    title: &str,
    units: &[Option<String>],
    mc: &McResult,
    gum: Option<&GumResult>,
) -> anyhow::Result<()> {
    let n = mc.outputs.len().max(1) as u32;
    with_backend(
        path,
        (1100, 380 * n),
        &|r| draw(r, title, units, mc, gum),
        &|r| draw(r, title, units, mc, gum),
    )
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    units: &[Option<String>],
    mc: &McResult,
    gum: Option<&GumResult>,
) -> anyhow::Result<()> {
    root.fill(&WHITE).map_err(e)?;
    let panels = root.split_evenly((mc.outputs.len().max(1), 1));
    for (j, panel) in panels.iter().enumerate().take(mc.outputs.len()) {
        let unit = units.get(j).cloned().flatten();
        draw_panel(panel, j, title, unit.as_deref(), mc, gum)?;
    }
    Ok(())
}

/// Decimals that show `u` with three significant digits (and its interval alike).
fn decimals_for(u: f64) -> usize {
    if u.is_finite() && u > 0.0 {
        (2.0 - u.log10().floor()).clamp(0.0, 12.0) as usize
    } else {
        4
    }
}

/// The histogram of the Monte Carlo values as a density, 80 bins over `lo..hi`.
fn density(values: &[f64], lo: f64, hi: f64) -> (f64, Vec<f64>) {
    let bins = 80usize;
    let w = (hi - lo) / bins as f64;
    let mut counts = vec![0usize; bins];
    for v in values {
        if *v >= lo && *v < hi {
            counts[(((v - lo) / w) as usize).min(bins - 1)] += 1;
        }
    }
    let dens = counts
        .iter()
        .map(|c| *c as f64 / (values.len() as f64 * w))
        .collect();
    (w, dens)
}

/// One output: histogram, MC interval, GUM density and interval; legend and the figures in
/// the column on the right.
fn draw_panel<DB: DrawingBackend>(
    panel: &DrawingArea<DB, Shift>,
    j: usize,
    title: &str,
    unit: Option<&str>,
    mc: &McResult,
    gum: Option<&GumResult>,
) -> anyhow::Result<()> {
    let (Some(o), Some(values)) = (mc.outputs.get(j), mc.values.get(j)) else {
        return Ok(());
    };
    let mut values = values.clone();
    values.sort_unstable_by(f64::total_cmp);
    let values = &values;
    if values.is_empty() {
        return Ok(());
    }
    let g = gum.and_then(|g| g.outputs.get(j));
    // Range: the central 99.9 % of the Monte Carlo values, widened to the GUM interval.
    let q = |p: f64| values[((values.len() - 1) as f64 * p) as usize];
    let (mut lo, mut hi) = (q(0.0005), q(0.9995));
    if let Some(g) = g {
        lo = lo.min(g.estimate - 3.5 * g.standard_uncertainty);
        hi = hi.max(g.estimate + 3.5 * g.standard_uncertainty);
    }
    if hi.is_nan() || hi <= lo {
        hi = lo + 1.0;
    }
    let (lo, hi) = axis_range((lo, hi));
    let (w, dens) = density(values, lo, hi);
    let mut ymax = dens.iter().cloned().fold(0.0, f64::max);
    if let Some(g) = g {
        ymax = ymax.max(1.0 / (g.standard_uncertainty * (std::f64::consts::TAU).sqrt()));
    }
    let caption = if j == 0 {
        format!("{title}: {}", o.name)
    } else {
        o.name.clone()
    };
    let (plot, side) = panel.split_horizontally(panel.dim_in_pixel().0 - 300);
    let mut chart = ChartBuilder::on(&plot)
        .caption(caption, (FONT, 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(lo..hi, 0.0..axis_range((0.0, ymax * 1.06)).1)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc(format!(
            "{}{}",
            o.name,
            unit.map(|u| format!(" / {u}")).unwrap_or_default()
        ))
        .y_desc("probability density")
        .x_labels(LABELS)
        .y_labels(LABELS)
        .x_label_formatter(&ticks((lo, hi)))
        .y_label_formatter(&ticks((0.0, ymax * 1.06)))
        .label_style((FONT, 13))
        .draw()
        .map_err(e)?;
    chart
        .draw_series(dens.iter().enumerate().map(|(i, d)| {
            let x0 = lo + i as f64 * w;
            Rectangle::new([(x0, 0.0), (x0 + w, *d)], MC.mix(0.45).filled())
        }))
        .map_err(e)?;
    let vertical = |x: f64| vec![(x, 0.0), (x, ymax * 1.03)];
    let [a, b] = o.symmetric_interval;
    chart
        .draw_series([a, b].map(|x| PathElement::new(vertical(x), MC.stroke_width(2))))
        .map_err(e)?;
    let d = decimals_for(o.standard_uncertainty);
    let mut block = vec![
        ("MC trials".to_string(), mc.trials.to_string()),
        ("MC y".to_string(), num(o.estimate, d)),
        ("MC u".to_string(), num(o.standard_uncertainty, d)),
    ];
    let mut legend = vec![
        (Mark::Bar(MC), "Monte Carlo".to_string()),
        (
            Mark::Line(MC),
            format!("{} % MC interval", num(100.0 * mc.coverage_probability, 0)),
        ),
    ];
    block.push((
        "MC interval".into(),
        format!("[{}, {}]", num(a, d), num(b, d)),
    ));
    if let Some(g) = g.filter(|g| g.standard_uncertainty > 0.0) {
        let s = g.standard_uncertainty;
        let pts: Vec<(f64, f64)> = (0..=400)
            .map(|i| {
                let x = lo + (hi - lo) * i as f64 / 400.0;
                let z = (x - g.estimate) / s;
                (
                    x,
                    (-0.5 * z * z).exp() / (s * (std::f64::consts::TAU).sqrt()),
                )
            })
            .collect();
        chart
            .draw_series(LineSeries::new(pts, GUM.stroke_width(2)))
            .map_err(e)?;
        let [c, dd] = g.interval;
        chart
            .draw_series(
                [c, dd].map(|x| DashedPathElement::new(vertical(x), 6, 4, GUM.stroke_width(1))),
            )
            .map_err(e)?;
        legend.push((Mark::Line(GUM), "GUM normal density".into()));
        legend.push((
            Mark::Dashed(GUM),
            format!("GUM y ± U (k = {})", num(g.coverage_factor, 2)),
        ));
        block.push(("GUM u".into(), num(s, d)));
        block.push((
            "GUM interval".into(),
            format!("[{}, {}]", num(c, d), num(dd, d)),
        ));
    }
    side_column(&side, 36, "figures", &block, &legend)
}
