//! ARCHITECTURE.md stays true: every file and folder it names exists, every Rust symbol it names
//! is defined in the workspace, and every folder of code is on the map. Paths use the document's key (`core/`, `data/`, `gpu/`, `cli/` for the
//! crates' `src/`, or their `tests/`, `benches/` and `assets/` folders; `shaders/` at the top);
//! in the data-flow diagram a bare file name is in the folder of the path before it on its line.
#![allow(clippy::unwrap_used, missing_docs)]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// File kinds whose names are checked.
const EXTENSIONS: [&str; 11] = ["rs", "wgsl", "md", "sh", "py", "toml", "json", "html", "png", "txt", "sha256"];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The repository path of a path written with the document's key, or `None` for what is not a
/// path in the repository (a run directory's files, tensor names, placeholders).
fn resolve(p: &str) -> Option<PathBuf> {
    let p = p.trim_end_matches([',', '.', ':', ';', ')']).trim_start_matches('(');
    let parts: Vec<&str> = p.split('/').filter(|s| !s.is_empty()).collect();
    let first = *parts.first()?;
    // Placeholders (RUN, RUN_DIR, NAME, ...) and run-directory contents are not repository files.
    let stem = |c: &&str| c.split('.').next().unwrap_or("").to_string();
    if parts
        .iter()
        .map(stem)
        .any(|c| c.len() > 1 && c.chars().all(|ch| ch.is_ascii_uppercase() || ch == '_' || ch.is_ascii_digit()))
    {
        return None;
    }
    let crate_dir = match first {
        "core" => Some("crates/mipnerf-core"),
        "gpu" => Some("crates/mipnerf-gpu"),
        "cli" => Some("crates/mipnerf-cli"),
        "data" => Some("crates/mipnerf-data"),
        _ => None,
    };
    if let Some(dir) = crate_dir {
        let rest = &parts[1..];
        let in_src = !matches!(rest.first().copied(), Some("tests" | "benches" | "assets"));
        let mut path = root().join(dir);
        if in_src {
            path.push("src");
        }
        rest.iter().for_each(|c| path.push(c));
        return Some(path);
    }
    let known = ["shaders", "crates", "scripts", "docs", "experiments", "tests", ".ci", "src", "examples"];
    let has_ext = parts.last().and_then(|l| l.rsplit_once('.')).is_some_and(|(_, e)| EXTENSIONS.contains(&e));
    (known.contains(&first) && (parts.len() > 1 || has_ext || p.ends_with('/'))).then(|| root().join(p))
}

/// `a/{b,c}.rs` as `a/b.rs` and `a/c.rs`.
fn expand(p: &str) -> Vec<String> {
    match (p.find('{'), p.find('}')) {
        (Some(i), Some(j)) if i < j => {
            p[i + 1..j].split(',').map(|alt| format!("{}{}{}", &p[..i], alt.trim(), &p[j + 1..])).collect()
        }
        _ => vec![p.to_string()],
    }
}

/// Every `.rs` and `.wgsl` file of the workspace (crates, tests, shaders), as one text.
fn sources() -> String {
    fn walk(dir: &Path, out: &mut String) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() && !p.ends_with("target") && !p.ends_with("tests/data") {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs" || x == "wgsl") {
                out.push_str(&std::fs::read_to_string(&p).unwrap());
                out.push('\n');
            }
        }
    }
    let mut all = String::new();
    for d in ["crates", "tests", "src", "shaders"] {
        let d = root().join(d);
        if d.is_dir() {
            walk(&d, &mut all);
        }
    }
    all
}

/// Names from outside the workspace that the document mentions: the browser's `EventSource`,
/// Rust's `Send` and `include_str!`, the `httparse` crate, wgpu's `WGPU_ADAPTER_NAME`.
const EXTERNAL: [&str; 5] = ["EventSource", "Send", "include_str", "httparse", "WGPU_ADAPTER_NAME"];

/// Whether `name` is defined in `src`: a function, type, trait, constant, static, module,
/// macro, enum variant or field.
fn defined(src: &str, name: &str) -> bool {
    let word = |prefix: &str| {
        src.match_indices(&format!("{prefix}{name}")).any(|(i, m)| {
            let after = src[i + m.len()..].chars().next().unwrap_or(' ');
            !(after.is_alphanumeric() || after == '_')
        })
    };
    EXTERNAL.contains(&name) || ["fn ", "struct ", "enum ", "trait ", "type ", "const ", "static ", "mod ", "macro_rules! "]
        .iter()
        .any(|k| word(k))
        // Enum variants and struct fields: `    Name,` / `    Name(` / `    Name {` / `pub name:`.
        || word("    ") && src.lines().any(|l| {
            let t = l.trim_start().trim_start_matches("pub ").trim_start_matches("pub(crate) ");
            t.strip_prefix(name).is_some_and(|r| r.starts_with([',', '(', ' ', ':', '{']) || r.is_empty())
        })
}

/// Folders of the map's scope: every folder that holds code (Rust, WGSL, shell or Python) outside
/// the build output, test data, results and experiments (each indexed by its own README), and
/// those folders themselves.
fn code_folders() -> Vec<PathBuf> {
    const SKIP: [&str; 3] = ["tests/data", "docs/results", "experiments"];
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        let rel = dir.strip_prefix(root()).unwrap();
        let skipped = SKIP.iter().any(|s| rel == Path::new(s));
        let entries: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().flatten().map(|e| e.path()).collect();
        let has_code = entries.iter().any(|p| {
            p.is_file() && p.extension().is_some_and(|x| ["rs", "wgsl", "sh", "py"].contains(&x.to_str().unwrap()))
        });
        if skipped || (has_code && dir != root()) || rel == Path::new(".ci") {
            out.push(dir.to_path_buf());
        }
        if skipped {
            return;
        }
        for p in entries {
            let name = p.file_name().unwrap().to_string_lossy().to_string();
            if p.is_dir() && !name.starts_with('.') && !name.contains("target") || name == ".ci" {
                walk(&p, out);
            }
        }
    }
    let mut out = Vec::new();
    walk(&root(), &mut out);
    out
}

/// Notes a path of the document (braces expanded) as named, or as missing.
fn check_file(p: &str, missing: &mut BTreeSet<String>, named: &mut BTreeSet<PathBuf>) {
    for f in expand(p) {
        match resolve(&f) {
            Some(path) if !path.exists() => {
                missing.insert(format!("file {f} ({})", path.display()));
            }
            Some(path) => {
                named.insert(path.components().collect());
            }
            None => {}
        }
    }
}

#[test]
fn every_file_and_symbol_architecture_md_names_exists() {
    let doc = std::fs::read_to_string(root().join("ARCHITECTURE.md")).unwrap();
    let src = sources();
    let mut named = BTreeSet::new();
    let mut missing = BTreeSet::new();
    let mut symbols_checked = 0;
    let mut in_diagram = false;
    for line in doc.lines() {
        if line.starts_with("```") {
            in_diagram = !in_diagram;
            continue;
        }
        if in_diagram {
            // The right-hand column: paths, some relative to the one before them on the line.
            let mut folder = String::new();
            for tok in line.split_whitespace() {
                let tok = tok.trim_matches([',', ';', '(', ')', ':']);
                let is_file = tok.rsplit_once('.').is_some_and(|(_, e)| e == "rs" || e == "wgsl");
                if !is_file || tok.chars().any(|c| c.is_ascii_uppercase()) {
                    if ["core", "data", "gpu", "cli"].contains(&tok) {
                        folder = format!("{tok}/");
                    }
                    continue;
                }
                let full = if tok.contains('/') && resolve(tok).is_some() {
                    tok.to_string()
                } else {
                    format!("{folder}{tok}")
                };
                if let Some(i) = full.rfind('/') {
                    folder = full[..=i].to_string();
                    if folder.contains('{') {
                        folder = full[..full.find('{').unwrap()].to_string();
                    }
                }
                check_file(&full, &mut missing, &mut named);
            }
            continue;
        }
        for (k, code) in line.split('`').enumerate() {
            if k % 2 == 0 || code.is_empty() || code.contains(' ') || code.starts_with('-') {
                continue;
            }
            if code.contains('/') || code.rsplit_once('.').is_some_and(|(_, e)| EXTENSIONS.contains(&e)) {
                check_file(code, &mut missing, &mut named);
                continue;
            }
            // Symbols: `Type::item`, `Type::item(..)`, `name()`, `CamelCase`, `snake_case_fn`.
            let sym = code.split('(').next().unwrap_or(code).trim_end_matches("!");
            let names: Vec<&str> = sym.split("::").filter(|s| !s.is_empty() && *s != "..").collect();
            let ident = |s: &&str| {
                s.chars().all(|c| c.is_alphanumeric() || c == '_')
                    && s.chars().next().is_some_and(|c| c.is_alphabetic())
            };
            if names.is_empty() || !names.iter().all(ident) {
                continue;
            }
            // A lone lower-case word is checked only when it reads as a function (has `_` or `()`).
            let lone_word = names.len() == 1
                && names[0].chars().next().unwrap().is_lowercase()
                && !names[0].contains('_')
                && !code.contains('(');
            if lone_word
                || names
                    .iter()
                    .any(|n| ["f32", "f64", "u32", "bf16", "usize", "std", "rayon", "wgpu", "naga"].contains(n))
            {
                continue;
            }
            for n in names {
                symbols_checked += 1;
                if !defined(&src, n) {
                    missing.insert(format!("symbol {n} (in `{code}`)"));
                }
            }
        }
    }
    assert!(
        named.len() > 30 && symbols_checked > 20,
        "too little checked: {} files, {symbols_checked} names",
        named.len()
    );
    // The other way round: every folder of code is on the map.
    for dir in code_folders() {
        if !named.contains(&dir) {
            missing.insert(format!("unmapped folder {}", dir.strip_prefix(root()).unwrap().display()));
        }
    }
    assert!(
        missing.is_empty(),
        "ARCHITECTURE.md names {} things that do not exist:\n{}",
        missing.len(),
        missing.into_iter().collect::<Vec<_>>().join("\n")
    );
}
