//! `render --path`'s video: an H.264 MP4 that decodes back (with OpenH264 and an MP4 reader, not
//! the writer's code) to the frames the render wrote as PNGs.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::{mipnerf, run_ok};

/// PSNR of each decoded frame against the PNG it was made from: H.264 at the render's bit rate
/// loses little on these smooth frames (measured 34 to 36 dB when written, chroma at half resolution the most of it); 30 dB is far above
/// a wrong frame or a shifted one.
const MIN_FRAME_PSNR: f64 = 30.0;

#[test]
fn a_path_render_writes_a_video_that_decodes_to_its_frames() {
    let dir = tempfile::tempdir().unwrap();
    let data = common::small_demo_scene(dir.path(), 4);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    run_ok(&["train", "--data", d, "--out", r, "--steps", "30", "--batch-rays", "128", "--backend", "cpu"]);
    let out = dir.path().join("orbit");
    let o = out.to_str().unwrap();
    // An odd width: H.264 takes whole chroma samples, so the video is one column narrower.
    let (frames, fps) = (6usize, 12u32);
    run_ok(&[
        "render",
        "--run",
        r,
        "--out",
        o,
        "--path",
        "orbit",
        "--frames",
        "6",
        "--fps",
        "12",
        "--width",
        "33",
        "--height",
        "24",
        "--backend",
        "cpu",
    ]);
    let bytes = std::fs::read(out.join("video.mp4")).unwrap();
    let size = bytes.len() as u64;
    let mut mp4 = mp4::Mp4Reader::read_header(std::io::Cursor::new(bytes), size).unwrap();
    let (&id, track) = mp4.tracks().iter().next().unwrap();
    assert_eq!((track.width(), track.height()), (32, 24));
    assert_eq!(track.media_type().unwrap(), mp4::MediaType::H264);
    assert_eq!(track.timescale(), fps);
    let (sps, pps) =
        (track.sequence_parameter_set().unwrap().to_vec(), track.picture_parameter_set().unwrap().to_vec());
    assert_eq!(mp4.sample_count(id).unwrap() as usize, frames);
    let mut decoder = openh264::decoder::Decoder::new().unwrap();
    let annex_b = |nal: &[u8]| [&[0, 0, 0, 1][..], nal].concat();
    let mut decoded = Vec::new();
    for i in 1..=frames as u32 {
        let sample = mp4.read_sample(id, i).unwrap().unwrap();
        assert_eq!((sample.start_time, sample.duration), (u64::from(i - 1), 1));
        assert_eq!(sample.is_sync, i == 1, "the first frame, and only it in half a second, is a key frame");
        // The sample's length-prefixed NAL units, in Annex B, after the parameter sets.
        let mut stream = if i == 1 { [annex_b(&sps), annex_b(&pps)].concat() } else { Vec::new() };
        let mut rest = &sample.bytes[..];
        while !rest.is_empty() {
            let n = u32::from_be_bytes(rest[..4].try_into().unwrap()) as usize;
            stream.extend(annex_b(&rest[4..4 + n]));
            rest = &rest[4 + n..];
        }
        if let Some(yuv) = decoder.decode(&stream).unwrap() {
            let mut rgb = vec![0u8; 32 * 24 * 3];
            yuv.write_rgb8(&mut rgb);
            decoded.push(rgb);
        }
    }
    for yuv in decoder.flush_remaining().unwrap() {
        let mut rgb = vec![0u8; 32 * 24 * 3];
        yuv.write_rgb8(&mut rgb);
        decoded.push(rgb);
    }
    assert_eq!(decoded.len(), frames);
    for (i, rgb) in decoded.iter().enumerate() {
        let png = image::open(out.join(format!("frame_{i:04}.png"))).unwrap().to_rgb8();
        assert_eq!(png.dimensions(), (33, 24));
        let se: f64 = (0..24u32)
            .flat_map(|y| (0..32u32).map(move |x| (x, y)))
            .flat_map(|(x, y)| {
                let p = png.get_pixel(x, y).0;
                (0..3).map(move |c| (f64::from(p[c]) - f64::from(rgb[((y * 32 + x) * 3) as usize + c])).powi(2))
            })
            .sum();
        let psnr = 10.0 * (255.0f64.powi(2) / (se / (32.0 * 24.0 * 3.0))).log10();
        eprintln!("frame {i}: {psnr:.1} dB against its PNG");
        assert!(psnr >= MIN_FRAME_PSNR, "frame {i}: {psnr:.1} dB");
    }
    // Frames too small for H.264: the render says so and writes the rest.
    let small = dir.path().join("small");
    let text = run_ok(&[
        "render",
        "--run",
        r,
        "--out",
        small.to_str().unwrap(),
        "--path",
        "orbit",
        "--frames",
        "2",
        "--width",
        "12",
        "--height",
        "12",
        "--backend",
        "cpu",
    ]);
    assert!(text.contains("no video.mp4") && small.join("preview.gif").is_file() && !small.join("video.mp4").exists());
    let bad = mipnerf(&["render", "--run", r, "--out", o, "--path", "orbit", "--fps", "0", "--overwrite"]);
    assert!(!bad.status.success() && String::from_utf8_lossy(&bad.stderr).contains("--fps"));
    // A real browser plays it: Chromium loads the video and reports its size and duration.
    let Some(chromium) = common::chromium("video.mp4") else { return };
    let page = out.join("play.html");
    std::fs::write(
        &page,
        "<!DOCTYPE html><html><body><video id=\"v\" src=\"video.mp4\" muted></video><p id=\"out\">waiting</p><script>\
         const v = document.getElementById('v'), o = document.getElementById('out');\
         v.addEventListener('loadeddata', () => { o.textContent = 'played ' + v.videoWidth + 'x' + v.videoHeight + ' ' + v.duration.toFixed(3); });\
         v.addEventListener('error', () => { o.textContent = 'error ' + (v.error && v.error.code); });\
         </script></body></html>",
    )
    .unwrap();
    let dom = std::process::Command::new(chromium)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=10000", "--dump-dom"])
        .arg(format!("file://{}", page.display()))
        .output()
        .unwrap();
    let dom = String::from_utf8_lossy(&dom.stdout);
    // 6 frames at 12 per second: half a second.
    assert!(dom.contains("<p id=\"out\">played 32x24 0.500</p>"), "{dom}");
}
