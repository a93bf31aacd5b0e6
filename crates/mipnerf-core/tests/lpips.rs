//! LPIPS against the reference implementation's values (both backbones, 64x64 and 200x200), an
//! independent numpy implementation on non-square crops, the weights' checksums, and clear errors
//! for bad weights and images.
#![allow(clippy::unwrap_used, missing_docs)]

use std::path::{Path, PathBuf};

use mipnerf_core::lpips::{Lpips, Net};
use safetensors::{Dtype, tensor::TensorView};
use sha2::{Digest, Sha256};

/// The reference is float32 jax; ours is float32 with another summation order (im2col blocks
/// through gemm). Measured: every golden case agrees to within 1e-7; the bound is 1e-5.
const TOL_LPIPS_GOLDEN: f64 = 1e-5;
/// Against the float64 numpy reference: the f32 rounding of 13 layers of activations.
const TOL_LPIPS_F64: f64 = 1e-5;

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/lpips")
}

/// `../shared/models/lpips`, or `None` (one line printed) when it is absent outside CI.
fn weights_dir(test: &str) -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/models/lpips");
    if dir.join("vgg16.safetensors").is_file() {
        return Some(dir);
    }
    assert!(std::env::var_os("CI").is_none(), "{test}: {} is absent in CI, which has ../shared", dir.display());
    eprintln!("SKIPPED {test}: {} is absent (get the weights with scripts/fetch-lpips-weights.sh)", dir.display());
    None
}

fn rgb(path: &Path) -> (usize, usize, Vec<f32>) {
    let img = image::open(path).unwrap().to_rgb8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    (w, h, img.into_raw().iter().map(|&b| f32::from(b) / 255.0).collect())
}

fn crop(img: &[f32], w: usize, cw: usize, ch: usize) -> Vec<f32> {
    (0..ch).flat_map(|y| img[y * w * 3..(y * w + cw) * 3].to_vec()).collect()
}

/// Checks every case of a JSON file, reporting all mismatches at once.
fn check_cases(file: &str, tol: f64, nets: &[(Net, Lpips)]) {
    let cases: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(data_dir().join(file)).unwrap()).unwrap();
    let mut bad = Vec::new();
    let mut n = 0;
    for c in cases["cases"].as_array().unwrap() {
        let (w, h, a) = rgb(&data_dir().join(c["reference"].as_str().unwrap()));
        let (_, _, b) = rgb(&data_dir().join(c["distorted"].as_str().unwrap()));
        let (cw, ch) = (
            c.get("width").map_or(w, |v| v.as_u64().unwrap() as usize),
            c.get("height").map_or(h, |v| v.as_u64().unwrap() as usize),
        );
        let (a, b) = (crop(&a, w, cw, ch), crop(&b, w, cw, ch));
        for (net, l) in nets {
            let want = c[net.name()].as_f64().unwrap();
            let got = l.distance(&a, &b, cw, ch).unwrap();
            n += 1;
            if (got - want).abs() > tol {
                bad.push(format!(
                    "{} vs {} ({cw}x{ch}, {}): {got} != {want}",
                    c["reference"],
                    c["distorted"],
                    net.name()
                ));
            }
        }
    }
    assert!(n >= 8, "{file}: only {n} comparisons");
    assert!(bad.is_empty(), "{file}: {} of {n} mismatches beyond {tol}:\n{}", bad.len(), bad.join("\n"));
}

fn both(dir: &Path) -> Vec<(Net, Lpips)> {
    [Net::Vgg16, Net::Alex].map(|n| (n, Lpips::load(&dir.join(n.file_name()), n).unwrap())).into()
}

#[test]
fn lpips_matches_the_reference_implementation() {
    let Some(dir) = weights_dir("lpips_matches_the_reference_implementation") else { return };
    check_cases("lpips_cases.json", TOL_LPIPS_GOLDEN, &both(&dir));
}

#[test]
fn lpips_of_non_square_images_matches_an_independent_implementation() {
    let Some(dir) = weights_dir("lpips_of_non_square_images_matches_an_independent_implementation") else { return };
    check_cases("nonsquare_cases.json", TOL_LPIPS_F64, &both(&dir));
}

#[test]
fn lpips_does_not_depend_on_the_thread_count() {
    let Some(dir) = weights_dir("lpips_does_not_depend_on_the_thread_count") else { return };
    let l = Lpips::load(&dir.join("vgg16.safetensors"), Net::Vgg16).unwrap();
    let (w, h, a) = rgb(&data_dir().join("ref_64.png"));
    let (_, _, b) = rgb(&data_dir().join("noise_64.png"));
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| l.distance(&a, &b, w, h));
    let three = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap().install(|| l.distance(&a, &b, w, h));
    assert_eq!(one.unwrap().to_bits(), three.unwrap().to_bits());
}

#[test]
fn the_weights_checksums_are_those_of_the_shared_files() {
    let Some(dir) = weights_dir("the_weights_checksums_are_those_of_the_shared_files") else { return };
    let sums =
        std::fs::read_to_string(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scripts/lpips-weights.sha256"))
            .unwrap();
    let mut checked = 0;
    for line in sums.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty()) {
        let (sum, file) = line.split_once(char::is_whitespace).unwrap();
        let bytes = std::fs::read(dir.join(file.trim())).unwrap();
        let got: String = Sha256::digest(&bytes).iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(got, sum, "{file}: the fetch script would install other bytes than ../shared holds");
        checked += 1;
    }
    assert_eq!(checked, 2);
}

/// Tensor names, dtypes and shapes of a weights file to write.
type Specs = Vec<(String, Dtype, Vec<usize>)>;
/// A change made to a valid weight set.
type Edit<'a> = &'a dyn Fn(&mut Specs);

/// A complete AlexNet weight set of small made-up values, with `edit` applied, as safetensors.
fn synthetic_alexnet(edit: &dyn Fn(&mut Specs)) -> Vec<u8> {
    let mut specs: Specs = Vec::new();
    for (i, (k, cin, cout)) in
        [(11, 3, 64), (5, 64, 192), (3, 192, 384), (3, 384, 256), (3, 256, 256)].into_iter().enumerate()
    {
        specs.push((format!("AlexNet_0/Conv_{i}/kernel"), Dtype::F32, vec![k, k, cin, cout]));
        specs.push((format!("AlexNet_0/Conv_{i}/bias"), Dtype::F32, vec![cout]));
    }
    for (l, c) in [64, 192, 384, 256, 256].into_iter().enumerate() {
        specs.push((format!("NetLinLayer_{l}/Conv_0/kernel"), Dtype::F32, vec![1, 1, c, 1]));
    }
    edit(&mut specs);
    let bufs: Vec<Vec<u8>> = specs
        .iter()
        .map(|(_, dt, shape)| {
            let n: usize = shape.iter().product::<usize>() * if *dt == Dtype::F64 { 8 } else { 4 };
            (0..n).map(|i| if i % 4 == 3 { 0x3c } else { 0 }).collect()
        })
        .collect();
    let views: Vec<(String, TensorView<'_>)> = specs
        .iter()
        .zip(&bufs)
        .map(|((name, dt, shape), b)| (name.clone(), TensorView::new(*dt, shape.clone(), b).unwrap()))
        .collect();
    safetensors::serialize(views, None).unwrap()
}

#[test]
fn bad_weights_are_clear_errors_naming_the_tensor() {
    let path = Path::new("weights/alexnet.safetensors");
    let ok = Lpips::from_bytes(&synthetic_alexnet(&|_| {}), path, Net::Alex).unwrap();
    let img = vec![0.5f32; 40 * 32 * 3];
    assert!(ok.distance(&img, &img, 40, 32).unwrap().abs() < 1e-12);
    let cases: [(&str, Edit<'_>, &str); 4] = [
        ("a missing tensor", &|s| s.retain(|t| t.0 != "AlexNet_0/Conv_3/bias"), "\"AlexNet_0/Conv_3/bias\" is missing"),
        ("a wrong shape", &|s| s[4].2 = vec![3, 3, 192, 383], "\"AlexNet_0/Conv_2/kernel\" has shape [3, 3, 192, 383]"),
        ("a wrong dtype", &|s| s[11].1 = Dtype::F64, "\"NetLinLayer_1/Conv_0/kernel\" is F64"),
        (
            "a missing linear layer",
            &|s| s.retain(|t| !t.0.starts_with("NetLinLayer_4")),
            "\"NetLinLayer_4/Conv_0/kernel\" is missing",
        ),
    ];
    for (what, edit, want) in cases {
        let err = Lpips::from_bytes(&synthetic_alexnet(edit), path, Net::Alex).unwrap_err().to_string();
        assert!(err.contains(want) && err.contains("weights/alexnet.safetensors"), "{what}: {err}");
    }
    let err = Lpips::from_bytes(b"not safetensors", path, Net::Alex).unwrap_err().to_string();
    assert!(err.contains("not a valid safetensors file"), "{err}");
    // VGG names in an AlexNet file: the first missing tensor is named.
    let err = Lpips::from_bytes(&synthetic_alexnet(&|_| {}), path, Net::Vgg16).unwrap_err().to_string();
    assert!(err.contains("\"VGG16_0/Conv_0/kernel\" is missing"), "{err}");
    let err = Lpips::load(Path::new("/nonexistent/alexnet.safetensors"), Net::Alex).unwrap_err().to_string();
    assert!(err.contains("/nonexistent/alexnet.safetensors"), "{err}");
}

#[test]
fn bad_images_are_clear_errors() {
    let l = Lpips::from_bytes(&synthetic_alexnet(&|_| {}), Path::new("w"), Net::Alex).unwrap();
    let img = vec![0.5f32; 40 * 32 * 3];
    let err = l.distance(&img, &img[..100], 40, 32).unwrap_err().to_string();
    assert!(err.contains("second image has 100 values"), "{err}");
    let small = vec![0.5f32; 30 * 30 * 3];
    let err = l.distance(&small, &small, 30, 30).unwrap_err().to_string();
    assert!(err.contains("at least 31x31"), "{err}");
    let mut nan = img.clone();
    nan[7] = f32::NAN;
    let err = l.distance(&img, &nan, 40, 32).unwrap_err().to_string();
    assert!(err.contains("non-finite"), "{err}");
}
