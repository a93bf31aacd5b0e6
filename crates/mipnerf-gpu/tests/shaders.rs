//! Every WGSL file in `shaders/` parses and validates with naga, every one is compiled into the
//! crate, and the Rust uniform structs have the sizes the WGSL declares.
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::PathBuf;

use mipnerf_gpu::GradientAtomics;
use mipnerf_gpu::kernels::{
    ALL_SOURCES, INCLUDED_SOURCES, SHARED_SOURCES, WgslStruct,
    adam::AdamParams,
    batch::{BatchParams, GpuView},
    cast_ipe::CastIpeParams,
    compact::{ExpandParams, GatherParams},
    compose, compose_with,
    fused_mlp::FusedMlpParams,
    matmul::MatmulParams,
    mlp_aux::AuxParams,
    occupancy::OccupancyParams,
    occupancy_update::{OccupancyUpdateParams, RefreshParams},
    prelude,
    render::RenderParams,
    sample::SampleParams,
    tri_mip::TriMipParams,
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
fn every_shader_file_parses_and_validates_as_composed() {
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
        if let Some((_, included)) = INCLUDED_SOURCES.iter().find(|(n, _)| *n == name) {
            // A file some kernels include reads their bindings: it is validated composed into
            // each of them (below).
            assert_eq!(&src, included, "{name} differs from the kernels' included source");
            assert!(
                ALL_SOURCES.iter().any(|s| s.includes.iter().any(|(n, _)| *n == name)),
                "{name} is included by no kernel"
            );
            continue;
        }
        if let Some((_, shared)) = SHARED_SOURCES.iter().find(|(n, _)| *n == name) {
            // The shared files, composed in front of every kernel; each also valid on its own
            // after the generated constants.
            assert_eq!(&src, shared, "{name} differs from the kernels' shared source");
            if let Err(e) = parse_and_validate(&name, &format!("{}\n{src}", prelude())) {
                failures.push(e);
            }
            continue;
        }
        let shader = ALL_SOURCES.iter().find(|s| s.file == name && s.own == src).unwrap_or_else(|| {
            panic!("{name} is in shaders/ but not compiled into mipnerf-gpu (kernels::ALL_SOURCES)")
        });
        if let Err(e) = parse_and_validate(&name, &compose(shader)) {
            failures.push(e);
        }
        // Kernels with shared gradients also as the devices with float atomics compile them.
        if src.contains("array<GradientAtomic>")
            && let Err(e) = parse_and_validate(&name, &compose_with(shader, GradientAtomics::Float))
        {
            failures.push(e);
        }
    }
    assert!(failures.is_empty(), "{} shader(s) failed:\n{}", failures.len(), failures.join("\n"));
}

#[test]
fn no_kernel_restates_what_the_shared_sources_define() {
    // The hash, the stream formula, the generated constants and the host's structs (declared from
    // their Rust definitions) live in one place each.
    for shader in ALL_SOURCES {
        let (name, src) = (shader.file, shader.own);
        for needle in [
            "fn pcg_hash",
            "747796405u",
            "const STREAM_",
            "const WORKGROUP",
            "* 8u + ",
            "@workgroup_size(64)",
            "struct Params",
        ] {
            assert!(!src.contains(needle), "{name} restates {needle:?}: use shaders/rng.wgsl or the prelude");
        }
    }
    let prelude = prelude();
    assert!(
        prelude.contains(&format!(
            "const STREAM_DENSITY_NOISE: u32 = {}u;",
            mipnerf_core::rng::Stream::DensityNoise as u32
        ))
    );
    assert!(
        prelude.contains(&format!("const ENCODING_NERF: u32 = {}u;", mipnerf_core::model::PointEncoding::Nerf as u32))
    );
}

#[test]
fn a_broken_shader_is_reported_with_its_location() {
    let err = parse_and_validate("broken.wgsl", "fn main() { let x: f32 = 1u; }").unwrap_err();
    assert!(err.contains("broken.wgsl"), "error does not name the file: {err}");
}

/// The layout of the struct named `name` in a WGSL module: its size and its members (name,
/// offset, WGSL type).
fn wgsl_struct(file: &str, src: &str, name: &str) -> (u32, Vec<(String, usize, String)>) {
    let (module, _) = parse_and_validate(file, src).unwrap();
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).unwrap();
    let (handle, ty) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(name))
        .unwrap_or_else(|| panic!("{file}: no struct {name}"));
    let naga::TypeInner::Struct { members, .. } = &ty.inner else { panic!("{file}: {name} is not a struct") };
    let type_name = |h: naga::Handle<naga::Type>| -> String {
        let scalar = |s: naga::Scalar| match (s.kind, s.width) {
            (naga::ScalarKind::Uint, 4) => "u32",
            (naga::ScalarKind::Sint, 4) => "i32",
            (naga::ScalarKind::Float, 4) => "f32",
            other => panic!("unexpected scalar {other:?}"),
        };
        match module.types[h].inner {
            naga::TypeInner::Scalar(s) => scalar(s).to_string(),
            naga::TypeInner::Vector { size, scalar: s } => format!("vec{}<{}>", size as u8, scalar(s)),
            ref other => format!("{other:?}"),
        }
    };
    let list =
        members.iter().map(|m| (m.name.clone().unwrap_or_default(), m.offset as usize, type_name(m.ty))).collect();
    (layouter[handle].size, list)
}

/// Asserts that the layout WGSL gives the declaration generated from `T` is `T`'s, member by
/// member and in size (a member WGSL aligns further than `#[repr(C)]`, a `vec4` after three
/// scalars say, or padding left out of `T`'s list, shows here).
fn check<T: WgslStruct>(file: &str, mismatches: &mut Vec<String>) {
    let src = compose(ALL_SOURCES.iter().find(|s| s.file == file).unwrap());
    let (size, wgsl) = wgsl_struct(file, &src, T::WGSL_NAME);
    let rust: Vec<(String, usize, String)> =
        T::members().into_iter().map(|m| (m.name, m.offset, m.ty.to_string())).collect();
    if rust != wgsl {
        mismatches.push(format!("{file} {}: Rust {rust:?}\n   WGSL {wgsl:?}", T::WGSL_NAME));
    }
    if size as usize != std::mem::size_of::<T>() {
        mismatches.push(format!("{file} {}: {} bytes in Rust, {size} in WGSL", T::WGSL_NAME, std::mem::size_of::<T>()));
    }
}

#[test]
fn uniform_structs_match_wgsl_member_by_member() {
    let mut mismatches = Vec::new();
    check::<CastIpeParams>("cast_ipe.wgsl", &mut mismatches);
    check::<MatmulParams>("matmul.wgsl", &mut mismatches);
    check::<AuxParams>("mlp_aux.wgsl", &mut mismatches);
    check::<RenderParams>("render.wgsl", &mut mismatches);
    check::<AdamParams>("adam.wgsl", &mut mismatches);
    check::<SampleParams>("sample.wgsl", &mut mismatches);
    check::<OccupancyParams>("occupancy.wgsl", &mut mismatches);
    check::<OccupancyUpdateParams>("occupancy_update.wgsl", &mut mismatches);
    check::<ViewEncParams>("view_enc.wgsl", &mut mismatches);
    check::<BatchParams>("batch.wgsl", &mut mismatches);
    check::<GatherParams>("gather.wgsl", &mut mismatches);
    check::<ExpandParams>("expand.wgsl", &mut mismatches);
    check::<TriMipParams>("tri_mip.wgsl", &mut mismatches);
    check::<FusedMlpParams>("fused_mlp.wgsl", &mut mismatches);
    check::<RefreshParams>("occupancy_refresh.wgsl", &mut mismatches);
    // The per-view camera record of batch.wgsl, read from a storage array.
    check::<GpuView>("batch.wgsl", &mut mismatches);
    assert!(mismatches.is_empty(), "{} mismatch(es):\n{}", mismatches.len(), mismatches.join("\n"));
}

#[test]
fn the_member_check_catches_two_swapped_fields_of_one_size() {
    // A Params whose first two u32 fields are swapped in the WGSL: the sizes agree, the members do not.
    let src = compose(&mipnerf_gpu::kernels::view_enc::SOURCE)
        .replacen("    n_rays: u32,\n", "    deg_view_: u32,\n", 1)
        .replacen("    deg_view: u32,\n", "    n_rays: u32,\n", 1)
        .replacen("    deg_view_: u32,\n", "    deg_view: u32,\n", 1);
    assert!(src.find("deg_view: u32") < src.find("n_rays: u32"), "the test's edit did not apply");
    let (_, wgsl) = wgsl_struct("swapped.wgsl", &src, "Params");
    let rust: Vec<(String, usize, String)> =
        ViewEncParams::members().into_iter().map(|m| (m.name, m.offset, m.ty.to_string())).collect();
    assert_ne!(rust, wgsl);
}

#[test]
fn the_storage_buffer_limit_is_what_the_busiest_kernel_binds() {
    let most = ALL_SOURCES.iter().map(|s| s.own.matches("var<storage").count()).max().unwrap();
    assert_eq!(most as u32, mipnerf_gpu::context::MIN_STORAGE_BUFFERS_PER_STAGE);
}

/// Numerics that hold on every vendor. WGSL promises no NaN semantics, so no
/// kernel tests for NaN by comparing a value with itself (`x != x`, `!(x == x)`); and none calls
/// `fma`, whose fusing a kernel could come to rely on (the sine reductions split their constants
/// so that the products are exact instead). The check itself is checked on the forms it rejects.
#[test]
fn no_kernel_tests_for_nan_by_self_comparison_or_relies_on_fma() {
    fn offences(src: &str) -> Vec<String> {
        let mut found = Vec::new();
        for (i, line) in src.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            let words: Vec<&str> = code
                .split(|c: char| !(c.is_alphanumeric() || c == '_' || c == '.'))
                .filter(|w| !w.is_empty())
                .collect();
            let compact: String = code.chars().filter(|c| !c.is_whitespace()).collect();
            if words.iter().any(|w| compact.contains(&format!("{w}!={w}")) || compact.contains(&format!("!({w}=={w})")))
            {
                found.push(format!("line {}: NaN test by self-comparison: {}", i + 1, line.trim()));
            }
            if compact.contains("fma(") {
                found.push(format!("line {}: fma: {}", i + 1, line.trim()));
            }
        }
        found
    }
    let mut bad = Vec::new();
    let files =
        ALL_SOURCES.iter().map(|s| (s.file, s.own)).chain(SHARED_SOURCES.iter().chain(&INCLUDED_SOURCES).copied());
    for (name, src) in files {
        bad.extend(offences(src).into_iter().map(|o| format!("{name} {o}")));
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
    for rejected in ["if (!(dist == dist)) {", "let nan = v != v;", "let r = fma(-k, C, x);"] {
        assert_eq!(offences(rejected).len(), 1, "{rejected}");
    }
}
