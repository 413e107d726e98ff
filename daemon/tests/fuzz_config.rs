//! The config parser (TOML → validation, `acquire::config`) against hostile input.
//!
//! - `replay_config_corpus` (CI): every file of `protocol/fuzz/corpus/config/` (the seeds and
//!   any crash found) gives a config or a `ConfigError`, never a panic; `valid_*` must load.
//! - `mutate_configs` (ignored; run by hand, see protocol/fuzz/README.md): a stable-toolchain
//!   mutation fuzzer without coverage feedback (the config parser lives in the binary's crate,
//!   whose whole dependency tree a cargo-fuzz build would instrument): byte flips, inserts,
//!   deletions, splices between seeds and TOML tokens, `FUZZ_ITERS` inputs (default 10^7).
//!   A panicking input is written to the corpus as `crash-<n>` and fails the test.

use std::path::{Path, PathBuf};

use metrolog::acquire::config::Config;

fn corpus_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../protocol/fuzz/corpus/config")
}

/// A directory with the files the seeds name (trajectory, CapBall transform), so validation
/// gets past them.
fn workdir() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(
        d.path().join("poses.csv"),
        "pose,x_mm,y_mm,z_mm\n1,0,0,0\n2,50,0,0\n",
    )
    .unwrap();
    std::fs::write(
        d.path().join("capball-T.csv"),
        "1,0,0,0\n0,1,0,0\n0,0,1,0\n0,0,0,1\n",
    )
    .unwrap();
    d
}

fn seeds() -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(corpus_dir())
        .unwrap()
        .map(|e| {
            let p = e.unwrap().path();
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

fn parse(dir: &Path, data: &[u8]) -> Option<Result<Config, String>> {
    let text = std::str::from_utf8(data).ok()?;
    Some(Config::parse(&dir.join("metrolog.toml"), text).map_err(|e| e.to_string()))
}

#[test]
fn replay_config_corpus() {
    let dir = workdir();
    let seeds = seeds();
    assert!(seeds.len() >= 3);
    for (name, data) in seeds {
        let r = parse(dir.path(), &data);
        if name.starts_with("valid_") {
            r.unwrap()
                .unwrap_or_else(|e| panic!("{name} does not load: {e}"));
        }
    }
}

const TOKENS: &[&str] = &[
    "=",
    "[",
    "]",
    "[[",
    "]]",
    "\"",
    "'",
    "\n",
    "#",
    ",",
    "{",
    "}",
    ".",
    "0",
    "-1",
    "1e400",
    "nan",
    "inf",
    "-inf",
    "0x181",
    "0x800",
    "true",
    "4294967296",
    "18446744073709551616",
    "\"\"\"",
    "\\u0000",
    "é",
    "[run]",
    "[capball]",
    "[trigger]",
    "[psd]",
    "[interferometer]",
    "[detector]",
    "port",
    "rate_hz",
    "samples",
    "poly",
    "transform",
    "trajectory",
    "slcan",
    "socketcan",
    "can_id",
    "baud",
    "min_sum_pa",
    "time_scale",
    "output_dir",
    "machine",
];

/// xorshift64*: reproducible inputs from a seed, no dependency.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn mutate(rng: &mut Rng, seeds: &[(String, Vec<u8>)], out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&seeds[rng.below(seeds.len())].1);
    for _ in 0..1 + rng.below(6) {
        let at = rng.below(out.len() + 1);
        match rng.below(6) {
            0 if at < out.len() => out[at] ^= 1 << rng.below(8),
            1 if at < out.len() => {
                let n = rng.below(32).min(out.len() - at);
                out.drain(at..at + n);
            }
            2 => {
                let t = TOKENS[rng.below(TOKENS.len())];
                out.splice(at..at, t.bytes());
            }
            3 => {
                let other = &seeds[rng.below(seeds.len())].1;
                let from = rng.below(other.len());
                let n = rng.below(200).min(other.len() - from);
                out.splice(at..at, other[from..from + n].iter().copied());
            }
            4 => out.insert(at, rng.next() as u8),
            _ if at < out.len() => out[at] = b"0123456789.-+e \n=[]\"#"[rng.below(21)],
            _ => {}
        }
    }
}

#[test]
#[ignore = "10^7 inputs: run by hand (protocol/fuzz/README.md)"]
fn mutate_configs() {
    let iters: u64 = std::env::var("FUZZ_ITERS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10_000_000);
    let seed: u64 = std::env::var("FUZZ_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0x5EED);
    let dir = workdir();
    let seeds = seeds();
    let mut rng = Rng(seed | 1);
    let mut input = Vec::new();
    let (mut ok, mut rejected, mut crashes) = (0u64, 0u64, 0u64);
    std::panic::set_hook(Box::new(|_| {}));
    for _ in 0..iters {
        mutate(&mut rng, &seeds, &mut input);
        match std::panic::catch_unwind(|| parse(dir.path(), &input)) {
            Ok(Some(Ok(_))) => ok += 1,
            Ok(_) => rejected += 1,
            Err(_) => {
                crashes += 1;
                std::fs::write(corpus_dir().join(format!("crash-{seed}-{crashes}")), &input)
                    .unwrap();
            }
        }
    }
    let _ = std::panic::take_hook();
    println!(
        "config fuzz: {iters} inputs (seed {seed}): {ok} valid, {rejected} rejected, {crashes} crashes"
    );
    assert_eq!(
        crashes,
        0,
        "crashing inputs written to {}",
        corpus_dir().display()
    );
}
