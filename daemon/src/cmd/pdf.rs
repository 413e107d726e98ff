//! The report as PDF: the self-contained HTML report printed by a headless Chromium
//! (`--print-to-pdf`). No Rust crate lays out HTML with inline SVG and print CSS; the browser
//! the report is already checked in (`daemon/tests/calibration_cli.rs`) does, and Debian ships
//! it as the package `chromium`. `docs/datasets.md` ("Report") says how the pages are laid out.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context as _, bail};

/// Browsers looked for on `PATH`, in this order.
const BROWSERS: [&str; 4] = [
    "chromium",
    "chromium-browser",
    "google-chrome",
    "google-chrome-stable",
];
/// A static page prints in a few seconds; a browser that takes this long has hung.
const PRINT_TIMEOUT: Duration = Duration::from_secs(180);

/// An executable file of that name in one of the `PATH` directories.
fn on_path(name: &str, path: Option<&std::ffi::OsStr>) -> Option<PathBuf> {
    use std::os::unix::fs::PermissionsExt as _;
    std::env::split_paths(path?)
        .map(|d| d.join(name))
        .find(|p| {
            std::fs::metadata(p).is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
        })
}

/// The browser to print with: `METROLOG_BROWSER` if set, else the first of [`BROWSERS`] on
/// `PATH`; an error that says what to install when there is none.
pub fn find_browser() -> anyhow::Result<PathBuf> {
    if let Some(b) = std::env::var_os("METROLOG_BROWSER").filter(|b| !b.is_empty()) {
        let p = PathBuf::from(&b);
        if p.is_file() {
            return Ok(p);
        }
        return on_path(&p.to_string_lossy(), std::env::var_os("PATH").as_deref()).with_context(
            || {
                format!(
                    "METROLOG_BROWSER is {}, which is not a file or a program on PATH",
                    p.display()
                )
            },
        );
    }
    let path = std::env::var_os("PATH");
    BROWSERS
        .iter()
        .find_map(|b| on_path(b, path.as_deref()))
        .with_context(|| {
            format!(
                "a PDF report is printed by a headless Chromium, and none was found on PATH \
                 (looked for {}): install it (Debian/Ubuntu: `apt-get install chromium`) or set \
                 METROLOG_BROWSER to the browser's executable; or write the report as HTML \
                 (-o report.html) and print that from any browser",
                BROWSERS.join(", ")
            )
        })
}

/// Prints `html` (a self-contained page) to the PDF file `out` with `browser`. The page and the
/// browser's profile live in a temporary directory; `out` is written only when the browser
/// produced a PDF.
pub fn html_to_pdf(browser: &Path, html: &str, out: &Path) -> anyhow::Result<()> {
    let dir = tempfile::tempdir().context("creating a temporary directory for the browser")?;
    let page = dir.path().join("report.html");
    let pdf = dir.path().join("report.pdf");
    let log = dir.path().join("browser.log");
    std::fs::write(&page, html).with_context(|| format!("writing {}", page.display()))?;
    let mut child = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-extensions",
            "--no-first-run",
            // The page's own header carries the date and the machine: no browser header/footer
            // (two spellings: newer and older Chromium).
            "--no-pdf-header-footer",
            "--print-to-pdf-no-header",
        ])
        .arg(format!(
            "--user-data-dir={}",
            dir.path().join("profile").display()
        ))
        .arg(format!("--print-to-pdf={}", pdf.display()))
        .arg(format!("file://{}", page.display()))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).context("creating the browser's log file")?)
        .spawn()
        .with_context(|| format!("starting {}", browser.display()))?;
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().context("waiting for the browser")? {
            break s;
        }
        if start.elapsed() > PRINT_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            bail!(
                "{} did not finish printing the report within {} s",
                browser.display(),
                PRINT_TIMEOUT.as_secs()
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let bytes = std::fs::read(&pdf).unwrap_or_default();
    if !status.success() || !bytes.starts_with(b"%PDF") {
        let err = std::fs::read_to_string(&log).unwrap_or_default();
        let tail: Vec<&str> = err.lines().rev().take(8).collect();
        bail!(
            "{} could not print the report to PDF ({status}); its last messages:\n{}",
            browser.display(),
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        );
    }
    std::fs::write(out, bytes).with_context(|| format!("writing {}", out.display()))
}
