//! Box-filter resampling of straight RGBA pixels: the official `down2`, and area averaging at
//! any ratio (masks and photos scaled to the training size).

/// The 2x2 box filter of straight RGBA `f32` pixels (`w x h`, both even): the official `down2`.
#[must_use]
pub fn down2(rgba: &[f32], w: usize, h: usize) -> Vec<f32> {
    let (w2, h2) = (w / 2, h / 2);
    let mut out = vec![0.0; w2 * h2 * 4];
    for y in 0..h2 {
        for x in 0..w2 {
            for c in 0..4 {
                let p = |dx: usize, dy: usize| rgba[((2 * y + dy) * w + 2 * x + dx) * 4 + c];
                // numpy's order for np.mean over the (row, column) pair axes.
                out[(y * w2 + x) * 4 + c] = (((p(0, 0) + p(1, 0)) + p(0, 1)) + p(1, 1)) / 4.0;
            }
        }
    }
    out
}

/// [`box_resize`] of 8-bit RGBA: to [0, 1], box-filtered, back to the nearest 8-bit value.
pub(crate) fn box_resize_rgba8(rgba: &[u8], w: u32, h: u32, nw: u32, nh: u32) -> Vec<u8> {
    let f: Vec<f32> = rgba.iter().map(|&b| f32::from(b) / 255.0).collect();
    let r = box_resize(&f, w as usize, h as usize, nw as usize, nh as usize);
    r.iter().map(|&x| (x * 255.0).round().clamp(0.0, 255.0) as u8).collect()
}

/// Area-average resampling of straight RGBA `f32` pixels from `w x h` to `nw x nh` (any ratio,
/// shrinking): each output pixel is the mean of the source area it covers, partly covered source
/// pixels weighted by the fraction covered. Separable: rows first, then columns, in `f64`.
/// For an exact factor of 2 it equals [`down2`] up to rounding.
///
/// # Panics
/// If `rgba` is shorter than `w * h * 4` or a target side is 0 or larger than the source's.
#[must_use]
pub fn box_resize(rgba: &[f32], w: usize, h: usize, nw: usize, nh: usize) -> Vec<f32> {
    assert!(rgba.len() >= w * h * 4, "box_resize: {} values for {w}x{h}", rgba.len());
    assert!(nw > 0 && nh > 0 && nw <= w && nh <= h, "box_resize: {w}x{h} -> {nw}x{nh}");
    // (first source index, weights) of each output index along one axis; weights sum to 1.
    let taps = |n: usize, src: usize| -> Vec<(usize, Vec<f64>)> {
        let scale = src as f64 / n as f64;
        (0..n)
            .map(|i| {
                let (a, b) = (i as f64 * scale, (i + 1) as f64 * scale);
                let first = a.floor() as usize;
                let last = (b.ceil() as usize).min(src);
                let ws =
                    (first..last).map(|s| ((s + 1) as f64).min(b) - (s as f64).max(a)).map(|c| c / scale).collect();
                (first, ws)
            })
            .collect()
    };
    let (tx, ty) = (taps(nw, w), taps(nh, h));
    let mut rows = vec![0.0f64; nw * h * 4];
    for y in 0..h {
        for (x, (first, ws)) in tx.iter().enumerate() {
            for c in 0..4 {
                rows[(y * nw + x) * 4 + c] =
                    ws.iter().enumerate().map(|(k, wt)| wt * f64::from(rgba[(y * w + first + k) * 4 + c])).sum();
            }
        }
    }
    let mut out = vec![0.0f32; nw * nh * 4];
    for (y, (first, ws)) in ty.iter().enumerate() {
        for x in 0..nw {
            for c in 0..4 {
                let v: f64 = ws.iter().enumerate().map(|(k, wt)| wt * rows[((first + k) * nw + x) * 4 + c]).sum();
                out[(y * nw + x) * 4 + c] = v as f32;
            }
        }
    }
    out
}
