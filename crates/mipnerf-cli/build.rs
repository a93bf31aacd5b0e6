//! Embeds the commit the binary is built from (`MIPNERF_COMMIT`), for the results it writes.

use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    out.status.success().then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn main() {
    let commit = git(&["rev-parse", "HEAD"]).map_or_else(
        || "unknown".to_string(),
        |c| {
            let dirty = git(&["status", "--porcelain", "--untracked-files=no"]).is_some_and(|s| !s.is_empty());
            if dirty { format!("{c}-dirty") } else { c }
        },
    );
    println!("cargo:rustc-env=MIPNERF_COMMIT={commit}");
    // Again when a commit is made or any source of the workspace changes (the dirty flag).
    if let Some(dir) = git(&["rev-parse", "--absolute-git-dir"]) {
        println!("cargo:rerun-if-changed={dir}/HEAD");
        println!("cargo:rerun-if-changed={dir}/index");
        println!("cargo:rerun-if-changed={dir}/refs");
    }
    for p in ["../../crates", "../../shaders", "../../Cargo.toml", "../../experiments"] {
        println!("cargo:rerun-if-changed={p}");
    }
}
