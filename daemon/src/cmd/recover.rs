//! `metrolog recover BROKEN.mcap -o FIXED.mcap`: rewrites the intact prefix of a torn or
//! killed log (power loss, SIGKILL, full disk) into a valid, indexed, cleanly closed file that
//! every MCAP tool opens whole (docs/log-format.md). The broken file is only read.

use std::path::PathBuf;

use anyhow::Context;

use super::progress::Progress;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The damaged log (.mcap); it is not changed.
    pub log: PathBuf,
    /// The new file (must not exist).
    #[arg(short = 'o', long = "output")]
    pub output: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // Written beside the output under a temporary name, renamed when complete: a failed
    // recover leaves no file behind.
    let tmp = super::input::new_output_path(&args.output)?;
    let bar = Progress::new("recover");
    let s = metrolog_log::recover::recover(&args.log, &tmp, |d, t| bar.update(d, t))
        .with_context(|| format!("cannot recover {}", args.log.display()))?;
    drop(bar);
    if let Some(note) = s.split_note() {
        errln!("note: {note}; written as one file");
    }
    anyhow::ensure!(
        s.messages > 0,
        "cannot recover {}: not one message could be read ({}); nothing written",
        args.log.display(),
        s.error.as_deref().unwrap_or("the log holds none")
    );
    super::input::finish_new_output(tmp, &args.output)?;
    match &s.error {
        None => outln!(
            "{} was intact (closed cleanly: {}); copied its {} messages to {}",
            args.log.display(),
            s.clean_close,
            s.messages,
            args.output.display()
        ),
        Some(e) => outln!(
            "recovered {} messages ({} of {} bytes read) into {}; damage: {e}",
            s.messages,
            s.bytes_read,
            s.file_bytes,
            args.output.display()
        ),
    }
}
