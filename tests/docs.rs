//! The documents a reader walks stay walkable: the README is a front door (at most
//! [`README_MAX_LINES`] lines, the guides linked from it), and every relative link or image of
//! the README, the changelog, the guides, the performance page and the results index points at a
//! file of the repository.
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::{Path, PathBuf};

/// The README's budget: what it is, the set-up, a quick start, one results table, links.
const README_MAX_LINES: usize = 250;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The documents whose links are checked, relative to the root.
fn documents() -> Vec<PathBuf> {
    let mut docs: Vec<PathBuf> =
        ["README.md", "CHANGELOG.md", "docs/performance.md", "docs/results/README.md"].map(PathBuf::from).to_vec();
    let mut guides: Vec<PathBuf> = std::fs::read_dir(root().join("docs/guide"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .map(|p| p.strip_prefix(root()).unwrap().to_path_buf())
        .collect();
    guides.sort();
    docs.extend(guides);
    docs
}

/// The targets of a markdown document's links and images (`](target)` and `src="target"`) that
/// are paths in the repository (not web addresses or anchors), anchors cut off.
fn relative_targets(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for (open, close) in [("](", ')'), ("src=\"", '"')] {
        let mut rest = text;
        while let Some(at) = rest.find(open) {
            rest = &rest[at + open.len()..];
            let Some(end) = rest.find(close) else { break };
            let target = &rest[..end];
            let external = ["http:", "https:", "mailto:", "#"].iter().any(|p| target.starts_with(p));
            if !external && !target.contains(' ') && !target.is_empty() {
                out.push(target.split('#').next().unwrap().to_string());
            }
        }
    }
    out
}

#[test]
fn the_readme_is_a_front_door_linking_every_guide() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let lines = readme.lines().count();
    assert!(lines <= README_MAX_LINES, "README.md has {lines} lines, at most {README_MAX_LINES}");
    for section in ["## Set-up: two commands", "## Quick start", "## Results", "## Guides"] {
        assert!(readme.contains(section), "README.md lacks {section}");
    }
    for guide in documents().iter().filter(|d| d.starts_with("docs/guide")) {
        let link = guide.to_str().unwrap();
        assert!(readme.contains(&format!("]({link})")), "README.md does not link {link}");
    }
}

#[test]
fn every_relative_link_of_the_documents_points_at_a_file() {
    let mut missing = Vec::new();
    let docs = documents();
    assert!(docs.len() > 8, "{docs:?}");
    for doc in &docs {
        let text = std::fs::read_to_string(root().join(doc)).unwrap();
        let dir = doc.parent().unwrap_or(Path::new(""));
        for target in relative_targets(&text) {
            if !root().join(dir).join(&target).exists() {
                missing.push(format!("{}: {target}", doc.display()));
            }
        }
    }
    assert!(missing.is_empty(), "{} link(s) to nothing:\n{}", missing.len(), missing.join("\n"));
}

#[test]
fn the_link_reader_finds_links_and_images_and_skips_the_web() {
    let text = "see [a](docs/a.md#x), ![b](../b.png) and [c](https://c) <img src=\"d.png\" width=\"9\">";
    assert_eq!(relative_targets(text), ["docs/a.md", "../b.png", "d.png"]);
}
