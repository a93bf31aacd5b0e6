//! The command line's names for the library's settings. The libraries' errors speak in library
//! terms: where the way out is a setting, they name it in backticks (`ProcessOptions::min_views`);
//! the CLI prints its flag in its place ([`in_flags`]).

/// Each library setting named in an error, and what the CLI says instead.
pub const FLAGS: [(&str, &str); 11] = [
    ("`ProcessOptions::min_views`", "--min-views"),
    ("`ProcessOptions::exclude`", "--exclude"),
    ("set `ProcessOptions::overwrite`", "pass --overwrite"),
    ("`DeviceOptions::adapter`", "--adapter, see 'mipnerf info'"),
    ("`DeviceOptions::memory_budget`", "--gpu-memory"),
    ("`BackendSetup::data`", "--batch-rays"),
    ("`BackendChoice::Cpu`", "--backend cpu"),
    ("`LoadOptions::half_res`", "--half-res"),
    ("`ModelConfig::supersample`", "--supersample"),
    ("`multiscale::convert_resized` makes smaller ones", "`mipnerf convert --size` makes smaller ones"),
    ("`colmap::convert_to_llff`", "mipnerf convert --to llff"),
];

/// `message` with the library's setting names replaced by the CLI's flags.
#[must_use]
pub fn in_flags(message: &str) -> String {
    FLAGS.iter().fold(message.to_string(), |m, (library, flag)| m.replace(library, flag))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every library source file's text, to check that each name of the table is still one
    /// the libraries use.
    fn library_sources() -> String {
        fn walk(dir: &std::path::Path, out: &mut String) {
            for e in std::fs::read_dir(dir).unwrap().flatten() {
                let p = e.path();
                if p.is_dir() {
                    walk(&p, out);
                } else if p.extension().is_some_and(|x| x == "rs") {
                    out.push_str(&std::fs::read_to_string(&p).unwrap());
                }
            }
        }
        let mut s = String::new();
        for c in ["mipnerf-core", "mipnerf-data", "mipnerf-gpu"] {
            walk(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(c).join("src"), &mut s);
        }
        s
    }

    #[test]
    fn every_library_setting_in_the_table_is_named_by_a_library_error_and_becomes_a_flag() {
        let src = library_sources();
        for (library, flag) in FLAGS {
            assert!(src.contains(library), "no library message names {library}: remove it from FLAGS");
            assert!(in_flags(&format!("x ({library}) y")).contains(flag));
        }
        let gpu = mipnerf_gpu::GpuError::Timeout { adapter: "llvmpipe".into(), seconds: 60.0 };
        let said = in_flags(&gpu.to_string());
        assert!(said.contains("(lower the rays per batch, --batch-rays)"), "{said}");
        assert!(!gpu.to_string().contains("--"), "the library speaks in its own terms: {gpu}");
    }
}
