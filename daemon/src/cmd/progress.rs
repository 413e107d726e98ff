//! A progress bar for commands that read a whole log (an 8-hour log is gigabytes): on stderr,
//! drawn only when stderr is a terminal (indicatif hides it otherwise), by bytes read.

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
    metrolog_analysis::LogContents::read_progress(path, |d, t| bar.update(d, t))
}
