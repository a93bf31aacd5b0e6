//! The real `mipnerf` binary, run as a user would.
#![allow(clippy::unwrap_used, missing_docs)]

use std::process::Command;

fn mipnerf(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_mipnerf")).args(args).env("XDG_RUNTIME_DIR", "/tmp").output().unwrap()
}

#[test]
fn info_prints_version_adapters_and_auto_choice() {
    let out = mipnerf(&["info"]);
    assert!(out.status.success(), "{out:?}");
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.starts_with(&format!("mipnerf {}", env!("CARGO_PKG_VERSION"))), "{text}");
    assert!(text.contains("GPU adapters"), "{text}");
    assert!(text.contains("--backend auto would use: "), "{text}");
    // Every adapter line names its backend, type and driver.
    for line in text.lines().filter(|l| l.starts_with("  - ")) {
        assert!(line.contains("| backend ") && line.contains("| type ") && line.contains("| driver "), "{line}");
    }
}

#[test]
fn a_wrong_subcommand_or_flag_fails_cleanly() {
    for args in [&["bogus"][..], &["check", "--backend", "tpu"][..], &["info", "--nope"][..]] {
        let out = mipnerf(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {out:?}");
        let err = String::from_utf8(out.stderr).unwrap();
        assert!(err.contains("error:") && !err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn check_compares_the_gpu_with_the_cpu_or_says_why_not() {
    let out = mipnerf(&["check", "--backend", "gpu"]);
    let text = String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    if out.status.success() {
        assert!(text.contains("max |gpu - cpu|") && text.trim_end().ends_with("ok"), "{text}");
    } else {
        // No adapter: a clear error, never a panic; CI always has one (lavapipe).
        assert!(std::env::var("CI").is_err(), "CI must have a GPU adapter: {text}");
        assert!(text.contains("no Vulkan/Metal/DX12 GPU adapter found") && !text.contains("panicked"), "{text}");
    }
}
