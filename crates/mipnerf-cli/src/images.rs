//! Writing pictures: PNG, float EXR, colour-mapped depth, animated GIF.

use std::path::Path;

use anyhow::{Context, Result, anyhow};

/// Linear `[0, 1]` RGB to 8-bit RGB (clamped, rounded).
#[must_use]
pub fn rgb_to_png(img: &[[f32; 3]]) -> Vec<u8> {
    img.iter().flat_map(|p| p.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8)).collect()
}

/// The prefix of the temporary name a picture is written under before it is renamed into place
/// (the extension is kept, so that the encoder is chosen by it).
pub const PARTIAL_PREFIX: &str = ".mipnerf-partial-";

/// Runs `write` on a temporary name beside `path` ([`PARTIAL_PREFIX`]) and renames the result
/// over `path`: a picture on disk is always whole, even when the process is killed mid-write.
fn atomically(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let name = path.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
    let tmp = path.with_file_name(format!("{PARTIAL_PREFIX}{name}"));
    if let Err(e) = write(&tmp) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))
}

/// Writes 8-bit RGB as PNG, whole or not at all.
///
/// # Errors
/// Unwritable file.
pub fn write_png(path: &Path, w: u32, h: u32, rgb: &[u8]) -> Result<()> {
    atomically(path, |tmp| {
        image::save_buffer(tmp, rgb, w, h, image::ExtendedColorType::Rgb8)
            .with_context(|| format!("writing {}", path.display()))
    })
}

/// Writes one float channel (named `channel`, e.g. "Z" or "A") as an uncompressed-float EXR.
///
/// # Errors
/// Unwritable file.
pub fn write_exr(path: &Path, w: usize, h: usize, channel: &str, values: &[f32]) -> Result<()> {
    use exr::prelude::*;
    let channels =
        AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new(channel, FlatSamples::F32(values.to_vec()))]));
    let image = Image::from_channels((w, h), channels);
    atomically(path, |tmp| image.write().to_file(tmp).map_err(|e| anyhow!("writing {}: {e}", path.display())))
}

/// The "turbo" colour map (Mikhailov 2019), polynomial approximation, `t` in `[0, 1]`.
#[must_use]
pub fn turbo(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let r = 0.135_721_38 + t * (4.615_392_6 + t * (-42.660_32 + t * (132.131_08 + t * (-152.942_4 + t * 59.286_38))));
    let g =
        0.091_402_61 + t * (2.194_188_4 + t * (4.842_966_6 + t * (-14.185_033 + t * (4.277_298_6 + t * 2.829_566))));
    let b = 0.106_673_3 + t * (12.641_946 + t * (-60.582_05 + t * (110.362_77 + t * (-89.903_11 + t * 27.348_25))));
    [r, g, b].map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8)
}

/// Depth as a colour-mapped PNG: near (`lo`) is blue, far (`hi`) red; transparent pixels
/// (opacity below 0.5) white.
#[must_use]
pub fn depth_to_png(depth: &[f32], acc: &[f32], lo: f32, hi: f32) -> Vec<u8> {
    let span = (hi - lo).max(1e-6);
    depth.iter().zip(acc).flat_map(|(&d, &a)| if a < 0.5 { [255, 255, 255] } else { turbo((d - lo) / span) }).collect()
}

/// Writes RGB frames as an animated GIF (looping, `delay_ms` per frame).
///
/// # Errors
/// Unwritable file or encoder failure.
pub fn write_gif(path: &Path, w: u32, h: u32, frames: &[Vec<u8>], delay_ms: u32) -> Result<()> {
    use image::codecs::gif::{GifEncoder, Repeat};
    atomically(path, |tmp| {
        let file = std::fs::File::create(tmp).with_context(|| format!("writing {}", path.display()))?;
        let mut enc = GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
        enc.set_repeat(Repeat::Infinite).map_err(|e| anyhow!("{}: {e}", path.display()))?;
        for rgb in frames {
            let rgba: Vec<u8> = rgb.chunks(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect();
            let buf = image::RgbaImage::from_raw(w, h, rgba).ok_or_else(|| anyhow!("frame size"))?;
            let frame = image::Frame::from_parts(buf, 0, 0, image::Delay::from_numer_denom_ms(delay_ms, 1));
            enc.encode_frame(frame).map_err(|e| anyhow!("{}: {e}", path.display()))?;
        }
        Ok(())
    })
}
