//! Split runs: one run written as several MCAP files ("parts"), like rosbag2's
//! `max_bagfile_duration` / `max_bagfile_size` (docs/log-format.md, "Split runs").
//!
//! A part is named `<run>-p<NNNN>.mcap` (`NNNN` from `0001`, so the names sort in the order
//! they were written); `<run>` is the name an unsplit run would have without `.mcap`
//! (`metrolog-<machine>-<UTC start>Z`). Each part is a complete MCAP file: schemas and
//! channels, the run metadata, the attachments and the last instrument metadata are repeated
//! at its start, followed by a `metrolog.part` metadata record ([`PART_METADATA`]); what comes
//! before that record in parts 2.. is a repeat, and a reader of the whole run skips it. A part
//! that was closed because the next one began ends with a `metrolog.part_next` record naming
//! it ([`PART_NEXT_METADATA`]), so a missing last part is seen as well as a missing middle one.
//!
//! Reading ([`resolve`]): the first part, any part, or a directory holding the parts of one
//! run all name the whole run; it is read from part 1 in order, and a missing part stops the
//! reading there with the gap as its error, like damage inside a file.

use std::path::{Path, PathBuf};

use super::LogError;

/// Metadata record that begins the part's own records: keys `run` (the run's name), `part`
/// (1-based number).
pub const PART_METADATA: &str = "metrolog.part";
/// Metadata record closing a part that has a successor: key `next` (the next part's file name).
pub const PART_NEXT_METADATA: &str = "metrolog.part_next";

/// The file name of part `part` (1-based) of run `run`.
pub fn part_name(run: &str, part: u32) -> String {
    format!("{run}-p{part:04}.mcap")
}

/// The run name and part number of a part's file name (`<run>-pNNNN.mcap`), if it is one.
pub fn parse_part_name(name: &str) -> Option<(&str, u32)> {
    let stem = name.strip_suffix(".mcap")?;
    let (run, num) = stem.rsplit_once("-p")?;
    if run.is_empty() || num.len() < 4 || !num.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let n: u32 = num.parse().ok()?;
    (n >= 1).then_some((run, n))
}

/// The run a file belongs to, by its name: a part's run name, or the file's own stem.
pub fn run_of_file_name(name: &str) -> &str {
    match parse_part_name(name) {
        Some((run, _)) => run,
        None => name.strip_suffix(".mcap").unwrap_or(name),
    }
}

/// What a path given to a reader names.
#[derive(Debug, Clone, PartialEq)]
pub enum Resolved {
    /// One file, not a part of a split run.
    Single(PathBuf),
    /// The parts of a split run found on disk, in part order.
    Split {
        run: String,
        parts: Vec<(u32, PathBuf)>,
    },
}

fn open_err(path: &Path, source: std::io::Error) -> LogError {
    LogError::Open {
        path: path.to_path_buf(),
        source,
    }
}

/// The parts of `run` in `dir`, sorted by part number.
fn parts_in(dir: &Path, run: &str) -> Result<Vec<(u32, PathBuf)>, LogError> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).map_err(|e| open_err(dir, e))? {
        let e = e.map_err(|e| open_err(dir, e))?;
        let name = e.file_name();
        let Some(name) = name.to_str() else { continue };
        if let Some((r, n)) = parse_part_name(name)
            && r == run
        {
            v.push((n, e.path()));
        }
    }
    v.sort();
    Ok(v)
}

/// The one run whose parts a directory holds.
fn run_in_dir(dir: &Path) -> Result<String, LogError> {
    let mut runs = std::collections::BTreeSet::new();
    for e in std::fs::read_dir(dir).map_err(|e| open_err(dir, e))? {
        let e = e.map_err(|e| open_err(dir, e))?;
        if let Some((run, _)) = e.file_name().to_str().and_then(parse_part_name) {
            runs.insert(run.to_string());
        }
    }
    let not = |reason: String| LogError::NotMcap {
        path: dir.to_path_buf(),
        reason,
    };
    match runs.len() {
        0 => Err(not(
            "it is not a regular file but a directory, and holds no parts of a split run (*-pNNNN.mcap)".into(),
        )),
        1 => Ok(runs.pop_first().unwrap_or_default()),
        n => Err(not(format!(
            "the directory holds the parts of {n} runs ({}); name one of their files",
            runs.into_iter().collect::<Vec<_>>().join(", ")
        ))),
    }
}

/// What `path` names: a part (any) or a directory of one run's parts is the whole split run;
/// anything else is one file.
pub fn resolve(path: &Path) -> Result<Resolved, LogError> {
    if path.is_dir() {
        let run = run_in_dir(path)?;
        let parts = parts_in(path, &run)?;
        return Ok(Resolved::Split { run, parts });
    }
    let name = path.file_name().and_then(|n| n.to_str());
    let Some((run, _)) = name.and_then(parse_part_name) else {
        return Ok(Resolved::Single(path.to_path_buf()));
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let parts = parts_in(dir, run)?;
    if parts.is_empty() {
        // The named file itself is missing: let the reader say so.
        return Ok(Resolved::Single(path.to_path_buf()));
    }
    Ok(Resolved::Split {
        run: run.to_string(),
        parts,
    })
}

/// The first missing part number of `parts` (sorted), if the numbering 1, 2, … has a hole.
pub fn first_gap(parts: &[(u32, PathBuf)]) -> Option<u32> {
    (1..)
        .zip(parts)
        .find(|(want, (n, _))| n != want)
        .map(|(want, _)| want)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn part_names_round_trip_and_sort_in_order() {
        let run = "metrolog-mill-1-20261127T203000Z";
        let names: Vec<String> = [1, 2, 10, 9999]
            .iter()
            .map(|&k| part_name(run, k))
            .collect();
        let mut sorted = names.clone();
        sorted.sort();
        assert_eq!(names, sorted);
        assert_eq!(parse_part_name(&names[2]), Some((run, 10)));
        assert_eq!(parse_part_name("metrolog-m-20261127T203000Z.mcap"), None);
        assert_eq!(parse_part_name("metrolog-m-p12.mcap"), None);
        assert_eq!(parse_part_name("metrolog-m-p0000.mcap"), None);
        assert_eq!(run_of_file_name("metrolog-a.mcap"), "metrolog-a");
        assert_eq!(run_of_file_name(&names[0]), run);
    }

    #[test]
    fn gaps_are_found() {
        let p =
            |v: &[u32]| -> Vec<(u32, PathBuf)> { v.iter().map(|&n| (n, PathBuf::new())).collect() };
        assert_eq!(first_gap(&p(&[1, 2, 3])), None);
        assert_eq!(first_gap(&p(&[1, 3])), Some(2));
        assert_eq!(first_gap(&p(&[2, 3])), Some(1));
    }
}
