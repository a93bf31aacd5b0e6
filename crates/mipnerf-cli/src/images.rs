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
    mipnerf_core::io::write_encoded(path, |bytes| {
        image::ImageEncoder::write_image(
            image::codecs::png::PngEncoder::new(bytes),
            rgb,
            w,
            h,
            image::ExtendedColorType::Rgb8,
        )
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
    mipnerf_core::io::write_encoded(path, |bytes| {
        image.write().non_parallel().to_buffered(bytes).map_err(|e| anyhow!("writing {}: {e}", path.display()))
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

/// The longest side of a path's animated preview, in pixels: larger frames are scaled down.
pub const PREVIEW_SIDE: u32 = 512;

/// The most frames a path's animated preview holds: a longer path shows every k-th frame.
pub const PREVIEW_FRAMES: usize = 120;

/// The delay between a preview's frames when it shows every frame, in milliseconds (12.5 frames
/// per second).
const PREVIEW_DELAY_MS: u32 = 80;

/// A path's animated preview (`preview.gif`), gathered frame by frame: at most
/// [`PREVIEW_FRAMES`] frames (every k-th of a longer path, each shown k times as long, up to a
/// second) of at most [`PREVIEW_SIDE`] pixels a side, so a path of any length and size is held in
/// a few tens of MB.
pub struct Preview {
    /// The frames' size, and the preview's.
    size: (u32, u32),
    scaled: (u32, u32),
    /// Every `stride`-th frame is kept.
    stride: usize,
    frames: Vec<Vec<u8>>,
}

impl Preview {
    /// A preview of `frames` frames of `w x h` pixels.
    #[must_use]
    pub fn new(frames: usize, w: u32, h: u32) -> Self {
        let scale = (f64::from(PREVIEW_SIDE) / f64::from(w.max(h))).min(1.0);
        // At most PREVIEW_SIDE, at least 1.
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let scaled = |x: u32| ((f64::from(x) * scale).round() as u32).max(1);
        Self {
            size: (w, h),
            scaled: (scaled(w), scaled(h)),
            stride: frames.div_ceil(PREVIEW_FRAMES).max(1),
            frames: Vec::new(),
        }
    }

    /// Takes frame `i` (8-bit RGB at the size given to [`Preview::new`]) if the preview shows it.
    ///
    /// # Errors
    /// A frame of another size.
    pub fn push(&mut self, i: usize, rgb: &[u8]) -> Result<()> {
        if !i.is_multiple_of(self.stride) {
            return Ok(());
        }
        let (w, h) = self.size;
        let frame = image::RgbImage::from_raw(w, h, rgb.to_vec())
            .ok_or_else(|| anyhow!("preview frame {i}: {} bytes, not {w}x{h} RGB", rgb.len()))?;
        let frame = if self.scaled == self.size {
            frame
        } else {
            image::imageops::resize(&frame, self.scaled.0, self.scaled.1, image::imageops::FilterType::Triangle)
        };
        self.frames.push(frame.into_raw());
        Ok(())
    }

    /// Writes the preview as a looping animated GIF, whole or not at all.
    ///
    /// # Errors
    /// Unwritable file or encoder failure.
    pub fn write(&self, path: &Path) -> Result<()> {
        use image::codecs::gif::{GifEncoder, Repeat};
        let (w, h) = self.scaled;
        let delay_ms = PREVIEW_DELAY_MS * u32::try_from(self.stride).unwrap_or(u32::MAX / PREVIEW_DELAY_MS).min(12);
        // Encoded in memory (its trailer is written when the encoder is dropped, at the end of
        // the closure), then written and checked whole.
        mipnerf_core::io::write_encoded(path, |bytes| {
            let mut enc = GifEncoder::new_with_speed(bytes, 10);
            enc.set_repeat(Repeat::Infinite).map_err(|e| anyhow!("{}: {e}", path.display()))?;
            for rgb in &self.frames {
                let rgba: Vec<u8> = rgb.chunks(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect();
                let buf = image::RgbaImage::from_raw(w, h, rgba).ok_or_else(|| anyhow!("frame size"))?;
                let frame = image::Frame::from_parts(buf, 0, 0, image::Delay::from_numer_denom_ms(delay_ms, 1));
                enc.encode_frame(frame).map_err(|e| anyhow!("{}: {e}", path.display()))?;
            }
            Ok(())
        })
    }
}

/// The H.264 quantiser of [`Video`] (0 lossless to 51; 20 is visually clean).
pub const VIDEO_QP: u8 = 20;

/// Smallest side H.264 takes here (one macroblock).
pub const MIN_VIDEO_SIDE: u32 = 16;

/// An H.264 MP4 written frame by frame, at `fps` frames per second, that browsers play: OpenH264
/// (constrained baseline, every 2 seconds a key frame) in an `avc1` track. Each frame is encoded
/// and written to the file's temporary name as it comes, so a video of any length holds one
/// frame in memory; [`Video::finish`] publishes the file whole, and a video dropped unfinished
/// (an error, a signal between frames) removes its temporary file, as does a signal that exits at
/// once ([`crate::signals::remove_on_exit`]). H.264 takes whole chroma samples, so an odd
/// width or height loses its last column or row.
pub struct Video {
    path: std::path::PathBuf,
    /// The frames' size, and the video's (even).
    size: (u32, u32),
    even: (u32, u32),
    fps: u32,
    encoder: openh264::encoder::Encoder,
    /// Opened on the first frame, when the encoder has given its parameter sets.
    writer: Option<mp4::Mp4Writer<std::io::BufWriter<std::fs::File>>>,
    frames: u64,
    cropped: Vec<u8>,
    finished: bool,
}

impl Video {
    /// A video of `w x h` frames at `fps` frames per second, to be published at `path`.
    ///
    /// # Errors
    /// Frames smaller than [`MIN_VIDEO_SIDE`], an `fps` outside 1 to 240, or an encoder error,
    /// naming the file.
    pub fn new(path: &Path, w: u32, h: u32, fps: u32) -> Result<Self> {
        use openh264::encoder::{Encoder, EncoderConfig, FrameRate, IntraFramePeriod, QpRange, RateControlMode};
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
        let encoder =
            Encoder::with_api_config(api, config).map_err(|e| anyhow!("{}: H.264 encoder: {e}", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            size: (w, h),
            even: (we, he),
            fps,
            encoder,
            writer: None,
            frames: 0,
            cropped: Vec::with_capacity((we * he * 3) as usize),
            finished: false,
        })
    }

    /// Encodes the next frame (8-bit RGB, `w x h`) and writes it to the file.
    ///
    /// # Errors
    /// A frame of another size, an encoder error or an unwritable file, named.
    pub fn push(&mut self, rgb: &[u8]) -> Result<()> {
        use openh264::formats::{RgbSliceU8, YUVBuffer};
        let ((w, h), (we, he)) = (self.size, self.even);
        let path = &self.path;
        let i = self.frames;
        if rgb.len() != (w * h * 3) as usize {
            anyhow::bail!("{}: frame {i} has {} bytes, not {w}x{h} RGB", path.display(), rgb.len());
        }
        self.cropped.clear();
        for row in rgb.chunks_exact(w as usize * 3).take(he as usize) {
            self.cropped.extend_from_slice(&row[..we as usize * 3]);
        }
        let yuv = YUVBuffer::from_rgb_source(RgbSliceU8::new(&self.cropped, (we as usize, he as usize)));
        let stream =
            self.encoder.encode(&yuv).map_err(|e| anyhow!("{}: H.264 frame {i}: {e}", path.display()))?.to_vec();
        // Annex B (start codes) to MP4's length-prefixed NAL units; the parameter sets go to the
        // track's avcC box.
        let (mut sps, mut pps) = (None, None);
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
        let err = |e: mp4::Error| anyhow!("writing {}: {e}", path.display());
        if self.writer.is_none() {
            let (Some(sps), Some(pps)) = (sps, pps) else {
                anyhow::bail!("{}: the H.264 encoder gave no parameter sets", path.display());
            };
            let tmp = mipnerf_core::io::partial_file(path);
            crate::signals::remove_on_exit(&tmp);
            let file = std::fs::File::create(&tmp).with_context(|| format!("writing {}", path.display()))?;
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
                timescale: self.fps,
                language: "und".to_string(),
                media_conf: mp4::MediaConfig::AvcConfig(avc),
            };
            writer.add_track(&track).map_err(err)?;
            self.writer = Some(writer);
        }
        let sample = mp4::Mp4Sample {
            start_time: i,
            duration: 1,
            rendering_offset: 0,
            is_sync: key,
            bytes: bytes::Bytes::from(sample),
        };
        self.writer.as_mut().map_or(Ok(()), |w| w.write_sample(1, &sample)).map_err(err)?;
        self.frames += 1;
        Ok(())
    }

    /// Finishes the file and publishes it under its name (synced, renamed).
    ///
    /// # Errors
    /// No frame was given, or the file could not be written, named.
    pub fn finish(mut self) -> Result<()> {
        let path = self.path.clone();
        let Some(mut writer) = self.writer.take() else { anyhow::bail!("{}: no frames", path.display()) };
        writer.write_end().map_err(|e| anyhow!("writing {}: {e}", path.display()))?;
        let mut file = writer.into_writer();
        std::io::Write::flush(&mut file).with_context(|| format!("writing {}", path.display()))?;
        drop(file);
        // The file is whole under its temporary name: synced, renamed over `path`.
        replace_with(&path, |_| Ok::<(), anyhow::Error>(()))?;
        self.finished = true;
        Ok(())
    }
}

impl Drop for Video {
    fn drop(&mut self) {
        let tmp = mipnerf_core::io::partial_file(&self.path);
        if !self.finished {
            let _ = std::fs::remove_file(&tmp);
        }
        crate::signals::keep_on_exit(&tmp);
    }
}

/// A NAL unit without its Annex B start code (`00 00 01` or `00 00 00 01`).
fn strip_start_code(nal: &[u8]) -> &[u8] {
    let zeros = nal.iter().take_while(|&&b| b == 0).count();
    if zeros >= 2 && nal.get(zeros) == Some(&1) { &nal[zeros + 1..] } else { nal }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A long path at a large size gives a preview of at most PREVIEW_FRAMES frames of at most
    /// PREVIEW_SIDE pixels, each frame of the path it shows scaled down whole; a short small path
    /// keeps every frame at its size.
    #[test]
    fn a_preview_is_bounded_in_frames_and_size() {
        use image::AnimationDecoder;
        let dir = tempfile::tempdir().unwrap();
        let frames = |path: &Path| {
            let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
            image::codecs::gif::GifDecoder::new(file).unwrap().into_frames().collect_frames().unwrap()
        };
        let (w, h) = (1024, 768);
        let mut preview = Preview::new(250, w, h);
        for i in 0..250 {
            // Frame i is grey level i: the preview shows frames 0, 3, 6, ...
            preview.push(i, &vec![i as u8; (w * h * 3) as usize]).unwrap();
        }
        let gif = dir.path().join("long.gif");
        preview.write(&gif).unwrap();
        let shown = frames(&gif);
        assert_eq!(shown.len(), 84);
        assert_eq!(shown[0].buffer().dimensions(), (PREVIEW_SIDE, 384));
        assert_eq!(shown[1].buffer().get_pixel(100, 100).0[..3], [3, 3, 3]);
        assert_eq!(shown[1].delay().numer_denom_ms(), (3 * PREVIEW_DELAY_MS, 1));
        let mut short = Preview::new(5, 40, 30);
        for i in 0..5 {
            short.push(i, &vec![50 * i as u8; 40 * 30 * 3]).unwrap();
        }
        let gif = dir.path().join("short.gif");
        short.write(&gif).unwrap();
        let shown = frames(&gif);
        assert_eq!((shown.len(), shown[4].buffer().dimensions()), (5, (40, 30)));
        assert!(short.push(5, &[0; 7]).unwrap_err().to_string().contains("not 40x30 RGB"));
    }

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
