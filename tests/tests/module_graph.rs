//! The workspace's module graph has no cycle of two: no two modules of a crate import each
//! other (docs/design.md, layout). Read from the sources, independently of the compiler: every
//! `crate::`/`super::`/`self::` path (in `use` trees and inline) is resolved to the module that
//! declares the item, following `pub use` re-exports, and an edge A → B is recorded when A names
//! an item of B. A parent's bare `mod child;` is not an edge (Rust needs it); using a child's
//! item is. Test modules (`#[cfg(test)] mod tests`) are left out.
//!
//! Run: `cargo test -p metrolog-hil --test module_graph` (prints every cycle it finds).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A module: its path in the crate (`a::b`, empty for the root) and its source without tests.
struct Module {
    path: Vec<String>,
    src: String,
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The member crates' `src` directories, from the workspace manifest.
fn crate_dirs() -> Vec<PathBuf> {
    let root = workspace_root();
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).expect("workspace Cargo.toml");
    let members = manifest
        .split("members = [")
        .nth(1)
        .and_then(|s| s.split(']').next())
        .expect("a members list");
    members
        .split(',')
        .map(|m| m.trim().trim_matches('"'))
        .filter(|m| !m.is_empty())
        .map(|m| root.join(m).join("src"))
        .filter(|p| p.join("lib.rs").exists())
        .collect()
}

fn rs_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).expect("readable src dir").flatten() {
        let p = e.path();
        if p.is_dir() {
            rs_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// `a/b.rs` and `a/b/mod.rs` → `["a", "b"]`; `lib.rs` → `[]`. `main.rs` and `bin/` are not
/// modules of the library.
fn module_path(src: &Path, file: &Path) -> Option<Vec<String>> {
    let rel = file.strip_prefix(src).ok()?;
    let mut parts: Vec<String> = rel
        .iter()
        .map(|s| s.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop()?;
    if parts.first().is_some_and(|p| p == "bin") || last == "main.rs" {
        return None;
    }
    match last.as_str() {
        "lib.rs" | "mod.rs" => {}
        name => parts.push(name.trim_end_matches(".rs").to_string()),
    }
    Some(parts)
}

/// The source up to its test module, without comments.
fn strip(src: &str) -> String {
    let mut out = String::new();
    let mut lines = src.lines().peekable();
    while let Some(line) = lines.next() {
        let t = line.trim_start();
        if t.starts_with("#[cfg(test)]") && lines.peek().is_some_and(|n| n.contains("mod tests")) {
            break;
        }
        if t.starts_with("//") {
            continue;
        }
        out.push_str(line.split(" //").next().unwrap_or(line));
        out.push('\n');
    }
    out
}

fn modules(src_dir: &Path) -> Vec<Module> {
    let mut files = Vec::new();
    rs_files(src_dir, &mut files);
    files
        .iter()
        .filter_map(|f| {
            let path = module_path(src_dir, f)?;
            let text = std::fs::read_to_string(f).ok()?;
            Some(Module {
                path,
                src: strip(&text),
            })
        })
        .collect()
}

/// Expands a `use` tree (`crate::{a::X, b::{Y, self}}`) into full paths.
fn expand(tree: &str) -> Vec<String> {
    let renamed = regex::Regex::new(r"\s+as\s+[A-Za-z_][A-Za-z0-9_]*").expect("regex");
    let tree: String = renamed
        .replace_all(tree, "")
        .chars()
        .filter(|c| !c.is_whitespace())
        .collect();
    let Some(open) = tree.find('{') else {
        return vec![tree];
    };
    let prefix = &tree[..open];
    let inner = &tree[open + 1..tree.len().saturating_sub(1)];
    split_top(inner)
        .into_iter()
        .flat_map(|part| expand(&part))
        .map(|p| {
            if p == "self" {
                prefix.trim_end_matches("::").to_string()
            } else {
                format!("{prefix}{p}")
            }
        })
        .collect()
}

/// Splits at the commas outside braces.
fn split_top(s: &str) -> Vec<String> {
    let (mut depth, mut cur, mut out) = (0, String::new(), Vec::new());
    for c in s.chars() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                out.push(std::mem::take(&mut cur));
                continue;
            }
            _ => {}
        }
        cur.push(c);
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    out.into_iter().filter(|p| !p.is_empty()).collect()
}

/// Every module-relative path a module names: `use` trees and inline `crate::`/`super::` paths.
fn named_paths(src: &str) -> Vec<(bool, String)> {
    let use_re =
        regex::Regex::new(r"(?m)^\s*(pub(?:\([a-z]+\))?\s+)?use\s+([A-Za-z0-9_:{},*\s]+);")
            .expect("regex");
    let inline_re =
        regex::Regex::new(r"\b((?:crate|super|self)(?:::[A-Za-z_][A-Za-z0-9_]*)+)").expect("regex");
    let mut out = Vec::new();
    for c in use_re.captures_iter(src) {
        let public = c.get(1).is_some();
        for p in expand(&c[2]) {
            out.push((public, p));
        }
    }
    let without_uses = use_re.replace_all(src, "");
    for c in inline_re.captures_iter(&without_uses) {
        out.push((false, c[1].to_string()));
    }
    out
}

/// A crate's modules and where each re-exported name comes from.
struct Crate {
    modules: BTreeSet<Vec<String>>,
    /// (module, name) → the path `pub use` gives for it, relative to that module.
    reexports: BTreeMap<(Vec<String>, String), String>,
}

impl Crate {
    /// The module a path (relative to module `from`) names an item of, following re-exports.
    fn resolve(&self, from: &[String], path: &str, depth: usize) -> Option<Vec<String>> {
        let mut segs = path.split("::");
        let mut cur: Vec<String> = match segs.next()? {
            "crate" => Vec::new(),
            "super" => from.get(..from.len().checked_sub(1)?)?.to_vec(),
            "self" => from.to_vec(),
            first => {
                // Relative to `from`: a child module of it, or else another crate (`None`: a
                // re-export of `types::Sample` is not an item of the module re-exporting it).
                let mut child = from.to_vec();
                child.push(first.to_string());
                if !self.modules.contains(&child) {
                    return None;
                }
                child
            }
        };
        let rest: Vec<&str> = segs.collect();
        let mut i = 0;
        while i < rest.len() {
            if rest[i] == "super" {
                cur.pop();
            } else {
                let mut next = cur.clone();
                next.push(rest[i].to_string());
                if !self.modules.contains(&next) {
                    break;
                }
                cur = next;
            }
            i += 1;
        }
        match rest.get(i) {
            Some(name) if depth < 8 => match self.reexports.get(&(cur.clone(), name.to_string())) {
                Some(target) => self.resolve(&cur, target, depth + 1),
                None => Some(cur),
            },
            _ => Some(cur),
        }
    }
}

fn edges(mods: &[Module]) -> BTreeSet<(Vec<String>, Vec<String>)> {
    let mut krate = Crate {
        modules: mods.iter().map(|m| m.path.clone()).collect(),
        reexports: BTreeMap::new(),
    };
    for m in mods {
        for (public, p) in named_paths(&m.src) {
            let name = p.rsplit("::").next().unwrap_or("").to_string();
            if public && !name.is_empty() {
                krate.reexports.insert((m.path.clone(), name), p.clone());
            }
        }
    }
    let mut out = BTreeSet::new();
    for m in mods {
        for (_, p) in named_paths(&m.src) {
            if let Some(to) = krate.resolve(&m.path, &p, 0)
                && to != m.path
            {
                out.insert((m.path.clone(), to));
            }
        }
    }
    out
}

fn show(path: &[String]) -> String {
    if path.is_empty() {
        "(root)".into()
    } else {
        path.join("::")
    }
}

#[test]
fn no_two_modules_import_each_other() {
    let mut cycles = Vec::new();
    let dirs = crate_dirs();
    assert!(dirs.len() >= 10, "workspace members not found: {dirs:?}");
    for dir in dirs {
        let e = edges(&modules(&dir));
        for (a, b) in &e {
            if a < b && e.contains(&(b.clone(), a.clone())) {
                let krate = dir
                    .parent()
                    .and_then(|p| p.file_name())
                    .map(|n| n.to_string_lossy().into_owned());
                cycles.push(format!(
                    "{}: {} ↔ {}",
                    krate.unwrap_or_default(),
                    show(a),
                    show(b)
                ));
            }
        }
    }
    assert!(
        cycles.is_empty(),
        "modules importing each other:\n{}",
        cycles.join("\n")
    );
}

/// The checker finds a cycle it is shown, and resolves re-exports and `use` trees.
#[test]
fn the_checker_sees_a_cycle_through_a_reexport() {
    let m = |p: &[&str], src: &str| Module {
        path: p.iter().map(|s| s.to_string()).collect(),
        src: strip(src),
    };
    let mods = [
        m(
            &[],
            "mod a;\nmod b;\npub use b::Thing;\npub use other::Sample;\n",
        ),
        m(&["a"], "use crate::{Thing, b::{self}};\npub struct A;\n"),
        m(
            &["b"],
            "pub struct Thing;\nfn f() -> crate::a::A { todo!() }\n",
        ),
    ];
    let e = edges(&mods);
    let a = vec!["a".to_string()];
    let b = vec!["b".to_string()];
    assert!(e.contains(&(a.clone(), b.clone())), "{e:?}");
    assert!(e.contains(&(b.clone(), a)), "{e:?}");
    assert!(
        e.contains(&(Vec::new(), b)),
        "the root re-exports b's item: {e:?}"
    );
}
