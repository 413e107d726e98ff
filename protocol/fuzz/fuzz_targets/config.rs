//! The daemon's config parser (TOML → validation, `metrolog::acquire::config`): any input gives
//! a config or a `ConfigError`, never a panic. The files the seeds name (a trajectory and a
//! CapBall transform) exist in a scratch directory so validation gets past them and into the
//! checks behind them. Coverage-guided companion of `daemon/tests/fuzz_config.rs`, which
//! replays this corpus in CI.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use metrolog::acquire::config::Config;

fn workdir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("metrolog-fuzz-config-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("scratch directory");
        std::fs::write(d.join("poses.csv"), "pose,x_mm,y_mm,z_mm\n1,0,0,0\n2,50,0,0\n")
            .expect("poses.csv");
        std::fs::write(
            d.join("capball-T.csv"),
            "1,0,0,0\n0,1,0,0\n0,0,1,0\n0,0,0,1\n",
        )
        .expect("capball-T.csv");
        d
    })
}

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = Config::parse(&workdir().join("metrolog.toml"), text);
    }
});
