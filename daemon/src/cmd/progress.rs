//! Progress bars on stderr, drawn only when stderr is a terminal (indicatif hides them
//! otherwise): bytes read of a whole log (an 8-hour log is gigabytes), and the trials of a
//! Monte Carlo.

use indicatif::{ProgressBar, ProgressStyle};

/// Bytes read of a file, with throughput and time left.
pub struct Progress(ProgressBar);

impl Progress {
    pub fn new(label: &str) -> Progress {
        let bar = ProgressBar::new(0);
        if let Ok(style) = ProgressStyle::with_template(
            "{msg} [{bar:30}] {bytes}/{total_bytes} {bytes_per_sec} eta {eta}",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message(label.to_string());
        Progress(bar)
    }

    /// For `read_log_progress`: `done` of `total` bytes.
    pub fn update(&self, done: u64, total: u64) {
        if self.0.length() != Some(total) {
            self.0.set_length(total);
        }
        self.0.set_position(done);
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.0.finish_and_clear();
    }
}

/// What the analyses need of the log at `path`, read with a progress bar labelled `label`.
pub fn read_contents(
    path: &std::path::Path,
    label: &str,
) -> Result<metrolog_analysis::LogContents, metrolog_analysis::AnalysisError> {
    let bar = Progress::new(label);
    let log = metrolog_analysis::LogContents::read_progress(path, |d, t| bar.update(d, t))?;
    drop(bar);
    if let Some(note) = log.summary.split_note() {
        eprintln!("note: {note}");
    }
    // Every analysis of a damaged log says so, and where, before its results.
    if let Some(d) = log.damage() {
        eprintln!(
            "warning: {} is damaged: {d}; the results are built on the part of the run before \
             the damage",
            path.display()
        );
    }
    Ok(log)
}

/// A Monte Carlo's bar: trials of a fixed number, or a spinner with the adaptive procedure's
/// state.
pub fn mc_progress_bar(opts: &uncertainty::McOptions) -> ProgressBar {
    match opts.fixed_trials {
        Some(n) => {
            let b = ProgressBar::new(n as u64);
            b.set_style(
                ProgressStyle::with_template("Monte Carlo {bar:40} {pos}/{len} trials ({eta})")
                    .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            b
        }
        None => {
            let b = ProgressBar::new_spinner();
            b.set_style(
                ProgressStyle::with_template("{spinner} adaptive Monte Carlo: {msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_spinner()),
            );
            b.enable_steady_tick(std::time::Duration::from_millis(120));
            b
        }
    }
}

/// Shows `p` on a bar of [`mc_progress_bar`].
pub fn update_mc_bar(b: &ProgressBar, p: &uncertainty::McProgress) {
    if b.length().is_some() {
        b.set_position(p.trials as u64);
    } else {
        let ratio = p
            .worst_ratio
            .map(|r| format!(", worst 2s/δ = {r:.2} (stops at ≤ 1)"))
            .unwrap_or_default();
        b.set_message(format!(
            "sequence {}, {} trials{ratio}",
            p.sequences, p.trials
        ));
    }
}
