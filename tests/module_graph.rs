//! The module graph stays layered (a reader can start at the bottom): in every crate, no top-level module names a module
//! that names it back, directly or through others (the graph of `crate::` references between a
//! crate's top-level modules has no cycle); no source file is over 800 lines; the CLI's `main.rs`
//! only dispatches (under 250); no function of the library code is over 120 lines.
//! `scripts/dev/module-graph.py` prints the same graph.
#![allow(clippy::unwrap_used, missing_docs)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The longest a source file may be.
const MAX_LINES: usize = 800;
/// The longest the CLI's `main.rs` may be.
const MAX_MAIN_LINES: usize = 250;

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// `src/foo.rs` and `src/foo/**.rs` are `foo`; `lib.rs` and `main.rs` are the crate root (none).
fn top_module(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).unwrap();
    let first = rel.components().next()?.as_os_str().to_string_lossy().into_owned();
    if rel.components().count() > 1 {
        return Some(first);
    }
    let stem = first.trim_end_matches(".rs");
    (stem != "lib" && stem != "main").then(|| stem.to_string())
}

/// The code of a file without `//` and `/* */` comments.
fn strip_comments(text: &str) -> String {
    let mut out = String::new();
    let mut rest = text;
    while let Some(i) = rest.find("/*") {
        out.push_str(&rest[..i]);
        rest = rest[i..].find("*/").map_or("", |j| &rest[i + j + 2..]);
    }
    out.push_str(rest);
    out.lines().map(|l| l.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n")
}

/// The top-level modules a file's code names through `crate::` (`crate::{a, b}` groups included).
fn crate_refs(code: &str) -> BTreeSet<String> {
    let word = |s: &str| s.trim().split(|c: char| !(c.is_alphanumeric() || c == '_')).next().unwrap_or("").to_string();
    let mut out = BTreeSet::new();
    for (i, _) in code.match_indices("crate::") {
        if code[..i].chars().next_back().is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue; // `mipnerf_crate::`, not this crate
        }
        let after = &code[i + "crate::".len()..];
        if let Some(group) = after.strip_prefix('{') {
            group.split('}').next().unwrap_or("").split(',').for_each(|p| {
                out.insert(word(p));
            });
        } else {
            out.insert(word(after));
        }
    }
    out.remove("");
    out
}

/// The modules on a cycle of `edges`, if any: repeatedly drops modules with no outgoing edge to a
/// module still left; what remains lies on or leads into a cycle, and is reported with its edges.
fn modules_on_cycles(edges: &BTreeMap<String, BTreeSet<String>>) -> BTreeMap<String, BTreeSet<String>> {
    let mut left = edges.clone();
    loop {
        let sinks: Vec<String> =
            left.iter().filter(|(_, to)| to.iter().all(|t| !left.contains_key(t))).map(|(m, _)| m.clone()).collect();
        if sinks.is_empty() {
            return left;
        }
        sinks.iter().for_each(|m| {
            left.remove(m);
        });
    }
}

#[test]
fn no_module_imports_one_that_imports_it_back_and_no_file_is_too_long() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut problems = Vec::new();
    for krate in ["mipnerf-core", "mipnerf-data", "mipnerf-gpu", "mipnerf-cli"] {
        let src = root.join("crates").join(krate).join("src");
        let mut files = Vec::new();
        rust_files(&src, &mut files);
        files.sort();
        let modules: BTreeSet<String> = files.iter().filter_map(|f| top_module(&src, f)).collect();
        let mut edges: BTreeMap<String, BTreeSet<String>> =
            modules.iter().map(|m| (m.clone(), BTreeSet::new())).collect();
        for f in &files {
            let text = std::fs::read_to_string(f).unwrap();
            let lines = text.lines().count();
            let limit = if f.ends_with("mipnerf-cli/src/main.rs") { MAX_MAIN_LINES } else { MAX_LINES };
            if lines > limit {
                problems.push(format!("{}: {lines} lines (at most {limit})", f.strip_prefix(&root).unwrap().display()));
            }
            let Some(m) = top_module(&src, f) else { continue };
            for r in crate_refs(&strip_comments(&text)) {
                if modules.contains(&r) && r != m {
                    edges.get_mut(&m).unwrap().insert(r);
                }
            }
        }
        for (m, to) in modules_on_cycles(&edges) {
            problems.push(format!("{krate}: {m} -> {to:?} lies on or leads into a cycle"));
        }
    }
    assert!(problems.is_empty(), "the module graph is not layered:\n{}", problems.join("\n"));
}

#[test]
fn the_cycle_finder_finds_a_cycle_and_passes_a_chain() {
    let graph = |pairs: &[(&str, &str)]| {
        let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
        for (a, b) in pairs {
            g.entry((*a).to_string()).or_default().insert((*b).to_string());
            g.entry((*b).to_string()).or_default();
        }
        g
    };
    assert!(modules_on_cycles(&graph(&[("cli", "run"), ("run", "plot"), ("plot", "io")])).is_empty());
    let left = modules_on_cycles(&graph(&[("eval", "html"), ("html", "plot"), ("plot", "eval"), ("plot", "io")]));
    assert_eq!(left.keys().cloned().collect::<Vec<_>>(), ["eval", "html", "plot"]);
    let code = "use crate::{a, b::C};\nfn f() { crate::d::g(); mipnerf_crate::x(); } // crate::e\n/* crate::f */";
    assert_eq!(crate_refs(&strip_comments(code)), ["a", "b", "d"].iter().map(|s| s.to_string()).collect());
}

/// The longest a function of the library code may be.
const MAX_FUNCTION_LINES: usize = 120;

/// Each function with a body in `code` (comments stripped): its name and its lines, from its
/// `fn` line to the brace that closes it (braces in strings and chars are rare enough here to
/// be ignored).
fn function_lengths(code: &str) -> Vec<(String, usize)> {
    let lines: Vec<&str> = code.lines().collect();
    let mut out = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let t = line.trim_start();
        let t = t.strip_prefix("pub ").or_else(|| t.strip_prefix("pub(crate) ")).unwrap_or(t);
        let t = t.strip_prefix("pub(super) ").unwrap_or(t);
        let t = t.strip_prefix("const ").unwrap_or(t);
        let t = t.strip_prefix("unsafe ").unwrap_or(t);
        let Some(rest) = t.strip_prefix("fn ") else { continue };
        let name: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
        let (mut depth, mut opened) = (0i64, false);
        for (j, l) in lines[i..].iter().enumerate() {
            if !opened && l.trim_end().ends_with(';') && !l.contains('{') {
                break;
            }
            depth += l.matches('{').count() as i64 - l.matches('}').count() as i64;
            opened |= l.contains('{');
            if opened && depth <= 0 {
                out.push((name.clone(), j + 1));
                break;
            }
        }
    }
    out
}

#[test]
fn no_function_of_the_library_code_is_longer_than_120_lines() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for krate in ["mipnerf-core", "mipnerf-data", "mipnerf-gpu", "mipnerf-cli"] {
        rust_files(&root.join("crates").join(krate).join("src"), &mut files);
    }
    rust_files(&root.join("src"), &mut files);
    files.sort();
    let mut long = Vec::new();
    for f in &files {
        for (name, n) in function_lengths(&strip_comments(&std::fs::read_to_string(f).unwrap())) {
            if n > MAX_FUNCTION_LINES {
                long.push(format!("{} {name}: {n} lines", f.strip_prefix(&root).unwrap().display()));
            }
        }
    }
    assert!(long.is_empty(), "functions over {MAX_FUNCTION_LINES} lines:\n{}", long.join("\n"));
}

#[test]
fn the_function_scan_measures_a_function_to_its_closing_brace() {
    let code = "pub fn a(x: u32) -> u32 {\n    if x > 0 {\n        1\n    } else {\n        2\n    }\n}\nfn b();\n";
    assert_eq!(function_lengths(code), vec![("a".to_string(), 7)]);
}
