//! `metrolog report`: the positioning report a customer signs, as one self-contained HTML
//! file (`metrolog_analysis::html_report`) or that page printed to PDF by a headless Chromium
//! (`cmd::pdf`), optionally with the CSV export.

use std::path::PathBuf;

use anyhow::Context as _;
use metrolog_analysis::html_report::{ReportHeader, ReportId, positioning_html};
use metrolog_analysis::positioning_report::{analyze_positioning_given, decide_tolerances};
use positioning::standards::{Standard, evaluate};

use crate::cmd::input::{load_positioning, print_out};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Positioning dataset (CSV, see datasets.md) or MCAP log of a run.
    pub input: PathBuf,
    #[command(flatten)]
    pub units: crate::cmd::input::UnitArgs,
    #[command(flatten)]
    pub tolerances: crate::cmd::input::ToleranceArgs,
    #[command(flatten)]
    pub assumed: crate::cmd::input::AssumeArgs,
    /// The report to write: `.html` (one self-contained page) or `.pdf` (that page printed by
    /// a headless Chromium: `apt-get install chromium`, or METROLOG_BROWSER=/path/to/browser).
    #[arg(long, short = 'o')]
    pub out: PathBuf,
    /// Also print the report to this PDF file (with an HTML `-o`).
    #[arg(long, value_name = "FILE")]
    pub pdf: Option<PathBuf>,
    /// Standards to evaluate by (repeat or comma-separate): iso230-2:2014, iso230-2:2006,
    /// iso230-2:1997, iso230-2:1988, vdi3441, asme-b5.54, jis-b6192, gb17421.2.
    #[arg(long, value_delimiter = ',', default_value = "iso230-2:2014")]
    pub standard: Vec<Standard>,
    /// Machine name [default: the dataset's `machine` metadata].
    #[arg(long)]
    pub machine: Option<String>,
    /// Operator [default: the dataset's `operator` metadata].
    #[arg(long)]
    pub operator: Option<String>,
    /// Date of the test [default: the dataset's `date` metadata].
    #[arg(long)]
    pub date: Option<String>,
    /// An instrument and its serial number (repeatable), e.g. "LI-80 s/n 12345".
    #[arg(long)]
    pub instrument: Vec<String>,
    /// Compensation active during the run, e.g. "none" or "SINUMERIK LEC 2026-11-20".
    #[arg(long)]
    pub compensation: Option<String>,
    /// Also write readings.csv, targets.csv and results.csv here.
    #[arg(long, value_name = "DIR")]
    pub csv: Option<PathBuf>,
}

/// The report ID of the input file: [`ReportId`] (FNV-1a 64) of its bytes, read in blocks.
fn input_id(p: &std::path::Path) -> anyhow::Result<String> {
    use std::io::Read as _;
    let mut f = std::fs::File::open(p).with_context(|| format!("reading {}", p.display()))?;
    let mut id = ReportId::default();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f
            .read(&mut buf)
            .with_context(|| format!("reading {}", p.display()))?;
        if n == 0 {
            return Ok(id.hex());
        }
        id.update(&buf[..n]);
    }
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let mut data = load_positioning(&a.input)?;
    a.units.apply(&mut data)?;
    let mut an = analyze_positioning_given(&data, None, |s| a.assumed.apply(s));
    an.conformance = decide_tolerances(&an, &a.tolerances.tolerance);
    let standards: Vec<_> = a.standard.iter().map(|s| evaluate(&data, *s)).collect();
    let mut h = ReportHeader::from_metadata(&data);
    h.machine = a.machine.clone().or(h.machine);
    h.operator = a.operator.clone().or(h.operator);
    h.date = a.date.clone().or(h.date);
    h.compensation = a.compensation.clone().or(h.compensation);
    h.instruments.extend(a.instrument.iter().cloned());
    h.report_id = Some(input_id(&a.input)?);
    let html = positioning_html(&data, &an, &standards, &h);
    let is_pdf = |p: &std::path::Path| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("pdf"));
    let pdfs: Vec<&PathBuf> = std::iter::once(&a.out)
        .filter(|p| is_pdf(p))
        .chain(&a.pdf)
        .collect();
    // Find the browser before anything is written, so that a missing one costs nothing.
    let browser = if pdfs.is_empty() {
        None
    } else {
        Some(crate::cmd::pdf::find_browser()?)
    };
    let mut msg = String::new();
    if !is_pdf(&a.out) {
        std::fs::write(&a.out, &html).with_context(|| format!("writing {}", a.out.display()))?;
        msg.push_str(&format!("report: {}\n", a.out.display()));
    }
    if let Some(b) = &browser {
        for p in pdfs {
            crate::cmd::pdf::html_to_pdf(b, &html, p)?;
            msg.push_str(&format!(
                "report: {} (printed by {})\n",
                p.display(),
                b.display()
            ));
        }
    }
    if let Some(dir) = &a.csv {
        for p in metrolog_analysis::export::write_csv_dir(dir, &data, &an.targets, &standards)
            .with_context(|| format!("writing CSV into {}", dir.display()))?
        {
            msg.push_str(&format!("csv: {}\n", p.display()));
        }
    }
    print_out(&msg)
}
