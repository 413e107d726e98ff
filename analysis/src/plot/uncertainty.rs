//! The Monte Carlo output distribution (histogram, as a probability density) beside the GUM
//! normal density, one panel per output; SVG or PNG by the file extension.

use std::path::Path;

use anyhow::{Context as _, anyhow, bail};
use metrology::uncertainty::{GumResult, McResult};
use plotters::coord::Shift;
use plotters::prelude::*;

use super::{FONT, ensure_font};

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
    ensure_font()?;
    let n = mc.outputs.len().max(1) as u32;
    let size = (900, 380 * n);
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("svg") => {
            let root = SVGBackend::new(path, size).into_drawing_area();
            draw(&root, title, units, mc, gum)?;
            root.present().map_err(|e| anyhow!("{e}"))
        }
        Some("png") => {
            let root = BitMapBackend::new(path, size).into_drawing_area();
            draw(&root, title, units, mc, gum)?;
            root.present().map_err(|e| anyhow!("{e}"))
        }
        _ => bail!(
            "cannot tell the plot format of {}: name it .svg or .png",
            path.display()
        ),
    }
    .with_context(|| format!("writing the plot {}", path.display()))
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    units: &[Option<String>],
    mc: &McResult,
    gum: Option<&GumResult>,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("{e}");
    root.fill(&WHITE).map_err(e)?;
    let panels = root.split_evenly((mc.outputs.len().max(1), 1));
    for (j, (o, panel)) in mc.outputs.iter().zip(panels).enumerate() {
        let values = &mc.sorted_values[j];
        if values.is_empty() {
            continue;
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
        let bins = 80usize;
        let w = (hi - lo) / bins as f64;
        let mut counts = vec![0usize; bins];
        for v in values {
            if *v >= lo && *v < hi {
                counts[(((v - lo) / w) as usize).min(bins - 1)] += 1;
            }
        }
        let dens: Vec<f64> = counts
            .iter()
            .map(|c| *c as f64 / (values.len() as f64 * w))
            .collect();
        let mut ymax = dens.iter().cloned().fold(0.0, f64::max);
        if let Some(g) = g {
            ymax = ymax.max(1.0 / (g.standard_uncertainty * (std::f64::consts::TAU).sqrt()));
        }
        let unit = units
            .get(j)
            .cloned()
            .flatten()
            .map(|u| format!(" / {u}"))
            .unwrap_or_default();
        let caption = if j == 0 {
            format!("{title}: {}", o.name)
        } else {
            o.name.clone()
        };
        let mut chart = ChartBuilder::on(&panel)
            .caption(caption, (FONT, 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(lo..hi, 0.0..ymax * 1.1)
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc(format!("{}{unit}", o.name))
            .y_desc("probability density")
            .label_style((FONT, 13))
            .draw()
            .map_err(e)?;
        chart
            .draw_series(dens.iter().enumerate().map(|(i, d)| {
                let x0 = lo + i as f64 * w;
                Rectangle::new([(x0, 0.0), (x0 + w, *d)], MC.mix(0.45).filled())
            }))
            .map_err(e)?
            .label(format!(
                "Monte Carlo, {} trials: u = {:.4}",
                mc.trials, o.standard_uncertainty
            ))
            .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 16, y + 5)], MC.mix(0.45).filled()));
        let [a, b] = o.symmetric_interval;
        chart
            .draw_series(
                [a, b].into_iter().map(|x| {
                    PathElement::new(vec![(x, 0.0), (x, ymax * 1.05)], MC.stroke_width(2))
                }),
            )
            .map_err(e)?
            .label(format!(
                "{:.0} % MC interval [{a:.4}, {b:.4}]",
                100.0 * mc.coverage_probability
            ))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], MC.stroke_width(2)));
        if let Some(g) = g {
            let s = g.standard_uncertainty;
            if s > 0.0 {
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
                    .map_err(e)?
                    .label(format!("GUM normal: u = {s:.4}"))
                    .legend(|(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], GUM.stroke_width(2))
                    });
                let [c, d] = g.interval;
                chart
                    .draw_series([c, d].into_iter().map(|x| {
                        PathElement::new(vec![(x, 0.0), (x, ymax * 1.05)], GUM.stroke_width(1))
                    }))
                    .map_err(e)?
                    .label(format!("GUM y ± U (k = {:.2})", g.coverage_factor))
                    .legend(|(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], GUM.stroke_width(1))
                    });
            }
        }
        chart
            .configure_series_labels()
            .label_font((FONT, 13))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(e)?;
    }
    Ok(())
}
