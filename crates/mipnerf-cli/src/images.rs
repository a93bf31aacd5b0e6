//! Writing pictures: PNG, float EXR, colour-mapped depth, animated GIF, H.264 video; each written
//! whole or not at all (`mipnerf_core::io::replace_with`: a temporary name, synced, renamed).

use std::path::Path;

use anyhow::{Context, Result, anyhow};
use mipnerf_core::io::replace_with;

/// Linear `[0, 1]` RGB to 8-bit RGB (clamped, rounded).
#[must_use]
pub fn rgb_to_png(img: &[[f32; 3]]) -> Vec<u8> {
    img.iter().flat_map(|p| p.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8)).collect()
}

/// Writes 8-bit RGB as PNG, whole or not at all.
///
/// # Errors
/// Unwritable file.
pub fn write_png(path: &Path, w: u32, h: u32, rgb: &[u8]) -> Result<()> {
    replace_with(path, |tmp| {
        image::save_buffer(tmp, rgb, w, h, image::ExtendedColorType::Rgb8)
            .with_context(|| format!("writing {}", path.display()))
    })
}

/// Writes one float channel (named `channel`, e.g. "Z" or "A") as a losslessly compressed `f32`
/// EXR. The blocks are compressed on one thread, in order: compressed on several, they land in the
/// file in the order the threads finish, so the same values gave different files.
///
/// # Errors
/// Unwritable file.
pub fn write_exr(path: &Path, w: usize, h: usize, channel: &str, values: &[f32]) -> Result<()> {
    use exr::prelude::*;
    let channels =
        AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new(channel, FlatSamples::F32(values.to_vec()))]));
    let image = Image::from_channels((w, h), channels);
    replace_with(path, |tmp| {
        image.write().non_parallel().to_file(tmp).map_err(|e| anyhow!("writing {}: {e}", path.display()))
    })
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
    replace_with(path, |tmp| {
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

/// The H.264 quantiser of [`write_mp4`] (0 lossless to 51; 20 is visually clean).
pub const VIDEO_QP: u8 = 20;

/// Smallest side H.264 takes here (one macroblock).
pub const MIN_VIDEO_SIDE: u32 = 16;

/// Writes `frames` (8-bit RGB, `w x h` each) as an H.264 MP4 at `fps` frames per second that
/// browsers play: OpenH264 (constrained baseline, every 2 seconds a key frame) in an `avc1`
/// track. H.264 takes whole chroma samples, so an odd width or height loses its last column or
/// row. Written to a temporary name and renamed.
///
/// # Errors
/// Frames smaller than [`MIN_VIDEO_SIDE`], an `fps` of 0, an encoder error, or an unwritable
/// file, named.
pub fn write_mp4(path: &Path, w: u32, h: u32, frames: &[Vec<u8>], fps: u32) -> Result<()> {
    use openh264::encoder::{Encoder, EncoderConfig, FrameRate, IntraFramePeriod, QpRange, RateControlMode};
    use openh264::formats::{RgbSliceU8, YUVBuffer};
    let (we, he) = (w & !1, h & !1);
    if we < MIN_VIDEO_SIDE || he < MIN_VIDEO_SIDE {
        anyhow::bail!(
            "{}: {w}x{h} frames are too small for H.264 (at least {MIN_VIDEO_SIDE} px a side)",
            path.display()
        );
    }
    if fps == 0 || fps > 240 {
        anyhow::bail!("{}: {fps} frames per second (1 to 240)", path.display());
    }
    // Constant quality (no rate control, so no frame is ever skipped): quantiser 20 keeps smooth
    // renders within about 2 dB of their PNGs, in a few MB a minute at 800 px.
    let config = EncoderConfig::new()
        .rate_control_mode(RateControlMode::Off)
        .qp(QpRange::new(VIDEO_QP, VIDEO_QP))
        .max_frame_rate(FrameRate::from_hz(fps as f32))
        .skip_frames(false)
        .intra_frame_period(IntraFramePeriod::from_num_frames(2 * fps));
    let api = openh264::OpenH264API::from_source();
    let mut encoder =
        Encoder::with_api_config(api, config).map_err(|e| anyhow!("{}: H.264 encoder: {e}", path.display()))?;
    let (mut sps, mut pps) = (None, None);
    let mut samples: Vec<(Vec<u8>, bool)> = Vec::with_capacity(frames.len());
    let mut cropped = Vec::with_capacity((we * he * 3) as usize);
    for (i, rgb) in frames.iter().enumerate() {
        if rgb.len() != (w * h * 3) as usize {
            anyhow::bail!("{}: frame {i} has {} bytes, not {w}x{h} RGB", path.display(), rgb.len());
        }
        cropped.clear();
        for row in rgb.chunks_exact(w as usize * 3).take(he as usize) {
            cropped.extend_from_slice(&row[..we as usize * 3]);
        }
        let yuv = YUVBuffer::from_rgb_source(RgbSliceU8::new(&cropped, (we as usize, he as usize)));
        let stream = encoder.encode(&yuv).map_err(|e| anyhow!("{}: H.264 frame {i}: {e}", path.display()))?.to_vec();
        // Annex B (start codes) to MP4's length-prefixed NAL units; the parameter sets go to the
        // track's avcC box.
        let (mut sample, mut key) = (Vec::new(), false);
        for nal in openh264::nal_units(&stream) {
            let body = strip_start_code(nal);
            match body.first().map(|b| b & 0x1f) {
                Some(7) => sps = sps.or_else(|| Some(body.to_vec())),
                Some(8) => pps = pps.or_else(|| Some(body.to_vec())),
                Some(t) => {
                    key |= t == 5;
                    sample.extend_from_slice(&(body.len() as u32).to_be_bytes());
                    sample.extend_from_slice(body);
                }
                None => {}
            }
        }
        samples.push((sample, key));
    }
    let (Some(sps), Some(pps)) = (sps, pps) else {
        anyhow::bail!("{}: the H.264 encoder gave no parameter sets", path.display());
    };
    replace_with(path, |tmp| {
        let err = |e: mp4::Error| anyhow!("writing {}: {e}", path.display());
        let file = std::fs::File::create(tmp).with_context(|| format!("writing {}", path.display()))?;
        let brand = |s: &str| s.parse::<mp4::FourCC>().map_err(|e| anyhow!("{e}"));
        let config = mp4::Mp4Config {
            major_brand: brand("isom")?,
            minor_version: 512,
            compatible_brands: vec![brand("isom")?, brand("iso2")?, brand("avc1")?, brand("mp41")?],
            timescale: 1000,
        };
        let mut writer = mp4::Mp4Writer::write_start(std::io::BufWriter::new(file), &config).map_err(err)?;
        let avc = mp4::AvcConfig { width: we as u16, height: he as u16, seq_param_set: sps, pic_param_set: pps };
        let track = mp4::TrackConfig {
            track_type: mp4::TrackType::Video,
            timescale: fps,
            language: "und".to_string(),
            media_conf: mp4::MediaConfig::AvcConfig(avc),
        };
        writer.add_track(&track).map_err(err)?;
        for (i, (bytes, key)) in samples.into_iter().enumerate() {
            let sample = mp4::Mp4Sample {
                start_time: i as u64,
                duration: 1,
                rendering_offset: 0,
                is_sync: key,
                bytes: bytes::Bytes::from(bytes),
            };
            writer.write_sample(1, &sample).map_err(err)?;
        }
        writer.write_end().map_err(err)?;
        Ok(())
    })
}

/// A NAL unit without its Annex B start code (`00 00 01` or `00 00 00 01`).
fn strip_start_code(nal: &[u8]) -> &[u8] {
    let zeros = nal.iter().take_while(|&&b| b == 0).count();
    if zeros >= 2 && nal.get(zeros) == Some(&1) { &nal[zeros + 1..] } else { nal }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_values_give_the_same_exr_file_and_read_back_exactly() {
        // Tall enough for many blocks (16 rows each), so that an order left to threads shows.
        let (w, h) = (37, 600);
        let values: Vec<f32> = (0..w * h).map(|i| (i as f32 * 0.37).sin() * 3.0 + 4.0).collect();
        let dir = tempfile::tempdir().unwrap();
        let files: Vec<Vec<u8>> = (0..4)
            .map(|i| {
                let path = dir.path().join(format!("depth{i}.exr"));
                write_exr(&path, w, h, "Z", &values).unwrap();
                std::fs::read(path).unwrap()
            })
            .collect();
        assert!(files.iter().all(|f| f == &files[0]), "the same depth map gave different files");
        let read = exr::prelude::read_first_flat_layer_from_file(dir.path().join("depth0.exr")).unwrap();
        let z = &read.layer_data.channel_data.list[0];
        assert_eq!(z.name.to_string(), "Z");
        let back: Vec<f32> = z.sample_data.values_as_f32().collect();
        assert!(back.iter().zip(&values).all(|(a, b)| a.to_bits() == b.to_bits()) && back.len() == values.len());
    }
}
