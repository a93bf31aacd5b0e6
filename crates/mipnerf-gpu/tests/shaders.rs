//! Every WGSL file in `shaders/` parses and validates with naga, every one is compiled into the
//! crate, and the Rust uniform structs have the sizes the WGSL declares.
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::PathBuf;

use mipnerf_gpu::kernels::{
    ALL_SOURCES,
    adam::AdamParams,
    batch::{BatchParams, GpuView},
    cast_ipe::CastIpeParams,
    matmul::MatmulParams,
    mlp_aux::AuxParams,
    render::RenderParams,
    sample::SampleParams,
    view_enc::ViewEncParams,
};

fn shaders_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shaders")
}

fn parse_and_validate(name: &str, src: &str) -> Result<(naga::Module, naga::valid::ModuleInfo), String> {
    let module = naga::front::wgsl::parse_str(src).map_err(|e| e.emit_to_string_with_path(src, name))?;
    let info = naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::all())
        .validate(&module)
        .map_err(|e| e.emit_to_string_with_path(src, name))?;
    Ok((module, info))
}

#[test]
fn every_shader_file_parses_and_validates() {
    let mut files: Vec<PathBuf> = std::fs::read_dir(shaders_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "wgsl"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no .wgsl files in {}", shaders_dir().display());
    let mut failures = Vec::new();
    for path in &files {
        let src = std::fs::read_to_string(path).unwrap();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        if let Err(e) = parse_and_validate(&name, &src) {
            failures.push(e);
        }
        assert!(
            ALL_SOURCES.iter().any(|(n, s)| *n == name && *s == src),
            "{name} is in shaders/ but not compiled into mipnerf-gpu (kernels::ALL_SOURCES)"
        );
    }
    assert!(failures.is_empty(), "{} shader(s) failed:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn a_broken_shader_is_reported_with_its_location() {
    let err = parse_and_validate("broken.wgsl", "fn main() { let x: f32 = 1u; }").unwrap_err();
    assert!(err.contains("broken.wgsl"), "error does not name the file: {err}");
}

/// The size in bytes of the struct named `name` in a WGSL module.
fn wgsl_struct_size(src: &str, name: &str) -> u32 {
    let (module, _) = parse_and_validate(name, src).unwrap();
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).unwrap();
    let (handle, _) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("no struct {name}"));
    layouter[handle].size
}

#[test]
fn uniform_structs_match_wgsl_sizes() {
    let rust_sizes = [
        ("cast_ipe.wgsl", std::mem::size_of::<CastIpeParams>()),
        ("matmul.wgsl", std::mem::size_of::<MatmulParams>()),
        ("mlp_aux.wgsl", std::mem::size_of::<AuxParams>()),
        ("render.wgsl", std::mem::size_of::<RenderParams>()),
        ("adam.wgsl", std::mem::size_of::<AdamParams>()),
        ("sample.wgsl", std::mem::size_of::<SampleParams>()),
        ("view_enc.wgsl", std::mem::size_of::<ViewEncParams>()),
        ("batch.wgsl", std::mem::size_of::<BatchParams>()),
    ];
    assert_eq!(rust_sizes.len(), ALL_SOURCES.len(), "every shader's uniform block is checked");
    for (file, size) in rust_sizes {
        let src = ALL_SOURCES.iter().find(|(n, _)| *n == file).unwrap().1;
        assert_eq!(wgsl_struct_size(src, "Params") as usize, size, "{file}: Params");
    }
    // The per-view camera record of batch.wgsl, read from a storage array.
    let batch = ALL_SOURCES.iter().find(|(n, _)| *n == "batch.wgsl").unwrap().1;
    assert_eq!(wgsl_struct_size(batch, "View") as usize, std::mem::size_of::<GpuView>(), "batch.wgsl: View");
}
