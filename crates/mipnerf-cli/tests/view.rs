//! `mipnerf view` and `train --view`: the live viewer's server answered over plain HTTP (its page,
//! the run's cameras and curves, frames, the coarse-to-fine stream, refusals), then its page in
//! headless Chromium, moving the camera with the page's own pointer handlers and checking that a
//! new frame arrives and is not blank; a screenshot is taken.
#![allow(clippy::unwrap_used, missing_docs)]

mod common;
use common::run_ok;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

/// A frame of the trained demo model has at least this many colours (measured: hundreds); a
/// blank or constant frame has one.
const MIN_FRAME_COLOURS: usize = 20;

/// A running server, killed when dropped.
struct Server {
    child: Child,
    addr: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `mipnerf ARGS` and waits for its "view: http://ADDR/" line.
fn start(args: &[&str]) -> Server {
    let mut child = common::command().args(args).stdout(Stdio::piped()).stderr(Stdio::inherit()).spawn().unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let addr = loop {
        let line = lines.next().expect("the server printed no URL").unwrap();
        if let Some(rest) = line.strip_prefix("view: http://") {
            break rest.split('/').next().unwrap().to_string();
        }
    };
    // Keep reading its output so that it never blocks on a full pipe.
    std::thread::spawn(move || lines.for_each(drop));
    Server { child, addr }
}

/// A GET over one connection: status, content type and body.
fn get(addr: &str, path: &str) -> (u16, String, Vec<u8>) {
    get_with(addr, path, &format!("Host: {addr}\r\n"))
}

/// [`get`] with the given header lines (each ending in CRLF) instead of the Host header.
fn get_with(addr: &str, path: &str, headers: &str) -> (u16, String, Vec<u8>) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    write!(s, "GET {path} HTTP/1.1\r\n{headers}Connection: close\r\n\r\n").unwrap();
    let mut bytes = Vec::new();
    s.read_to_end(&mut bytes).unwrap();
    let end = bytes.windows(4).position(|w| w == b"\r\n\r\n").expect("no header end") + 4;
    let head = String::from_utf8_lossy(&bytes[..end]).to_string();
    let status = head.split_whitespace().nth(1).unwrap().parse().unwrap();
    let content_type = head
        .lines()
        .find_map(|l| l.to_ascii_lowercase().strip_prefix("content-type:").map(|v| v.trim().to_string()))
        .unwrap_or_default();
    let mut body = bytes[end..].to_vec();
    if head.to_ascii_lowercase().contains("transfer-encoding: chunked") {
        body = dechunk(&body);
    }
    (status, content_type, body)
}

/// The body of a chunked HTTP response.
fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let eol = b.windows(2).position(|w| w == b"\r\n").unwrap();
        let n = usize::from_str_radix(std::str::from_utf8(&b[..eol]).unwrap().trim(), 16).unwrap();
        if n == 0 {
            return out;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + n]);
        b = &b[eol + 2 + n + 2..];
    }
}

fn png_size(png: &[u8]) -> (u32, u32) {
    let img = image::load_from_memory_with_format(png, image::ImageFormat::Png).unwrap();
    (img.width(), img.height())
}

fn distinct_colours(img: &image::RgbImage) -> usize {
    img.pixels().map(|p| p.0).collect::<std::collections::HashSet<_>>().len()
}

/// A camera query for the run's first test camera.
fn query(info: &serde_json::Value, w: u32, h: u32) -> String {
    let c2w: Vec<String> = info["start"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|r| r.as_array().unwrap().clone())
        .map(|x| x.to_string())
        .collect();
    format!("c2w={}&width={w}&height={h}&fov={}", c2w.join(","), info["fov"])
}

/// `text` with its `%XX` escapes (as `encodeURIComponent` writes them) decoded.
fn percent_decoded(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            out.push(u8::from_str_radix(&text[i + 1..i + 3], 16).unwrap());
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).unwrap()
}

#[test]
fn the_viewer_serves_frames_coarse_to_fine_and_a_browser_moves_its_camera() {
    let dir = tempfile::tempdir().unwrap();
    let data = common::demo_scene(dir.path(), 32, 16);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    run_ok(&[
        "train",
        "--data",
        d,
        "--out",
        r,
        "--preset",
        "fast",
        "--steps",
        "300",
        "--batch-rays",
        "1024",
        "--backend",
        "cpu",
        "--val-every",
        "150",
        "--val-images",
        "1",
        "--quiet",
    ]);
    let server = start(&["view", "--run", r, "--port", "0"]);
    let addr = server.addr.as_str();
    assert!(addr.starts_with("127.0.0.1:"), "binds to loopback by default: {addr}");

    let (status, ty, page) = get(addr, "/");
    assert_eq!((status, ty.as_str()), (200, "text/html; charset=utf-8"));
    let page = String::from_utf8(page).unwrap();
    assert!(
        page.contains("EventSource(") && !page.contains("http://") && !page.contains("https://"),
        "no external assets"
    );

    let (status, _, info) = get(addr, "/api/info");
    assert_eq!(status, 200);
    let info: serde_json::Value = serde_json::from_slice(&info).unwrap();
    assert_eq!(info["cameras"]["train"].as_array().unwrap().len(), 16);
    assert_eq!(info["cameras"]["test"].as_array().unwrap().len(), 1);

    let (status, ty, png) = get(addr, &format!("/api/render?{}", query(&info, 24, 20)));
    assert_eq!((status, ty.as_str()), (200, "image/png"));
    assert_eq!(png_size(&png), (24, 20));
    let frame = image::load_from_memory(&png).unwrap().to_rgb8();
    assert!(distinct_colours(&frame) >= MIN_FRAME_COLOURS, "a blank frame: {} colours", distinct_colours(&frame));

    // The stream: 1/8, 1/4, 1/2 and full size (never under 8 px), then `done`.
    let (status, ty, sse) = get(addr, &format!("/api/stream?{}", query(&info, 96, 80)));
    assert_eq!((status, ty.as_str()), (200, "text/event-stream"));
    let sse = String::from_utf8(sse).unwrap();
    let frames: Vec<serde_json::Value> = sse
        .lines()
        .filter_map(|l| l.strip_prefix("data: "))
        .filter(|d| *d != "{}")
        .map(|d| serde_json::from_str(d).unwrap())
        .collect();
    let sizes: Vec<(u64, u64)> =
        frames.iter().map(|f| (f["width"].as_u64().unwrap(), f["height"].as_u64().unwrap())).collect();
    assert_eq!(sizes, [(12, 10), (24, 20), (48, 40), (96, 80)]);
    for f in &frames {
        use base64::Engine;
        let png = base64::engine::general_purpose::STANDARD.decode(f["png"].as_str().unwrap()).unwrap();
        assert_eq!(png_size(&png), (f["width"].as_u64().unwrap() as u32, f["height"].as_u64().unwrap() as u32));
        assert_eq!(f["step"], 300);
    }
    assert!(sse.trim_end().ends_with("event: done\ndata: {}"), "{sse}");

    // A moved camera supersedes the refinement under way: a 1024 px stream, once its first
    // level is in, is dropped for a newer one (which finishes) and says so.
    let mut big = TcpStream::connect(addr).unwrap();
    big.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    write!(big, "GET /api/stream?{} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n", query(&info, 1024, 1024))
        .unwrap();
    let mut big = BufReader::new(big);
    let mut line = String::new();
    while !line.starts_with("data: ") {
        line.clear();
        big.read_line(&mut line).unwrap();
    }
    assert!(line.contains("\"width\":128"), "the 1/8 level first: {}", &line[..line.len().min(80)]);
    let (status, _, sse) = get(addr, &format!("/api/stream?{}", query(&info, 16, 16)));
    assert_eq!(status, 200);
    assert!(String::from_utf8(sse).unwrap().trim_end().ends_with("event: done\ndata: {}"), "the newer stream finishes");
    let mut rest = String::new();
    big.read_to_string(&mut rest).unwrap();
    assert!(rest.contains("event: failed") && rest.contains("superseded by a newer view"), "{rest}");
    assert!(!rest.contains("event: done"), "{rest}");

    // Curves, and the latest validation renders (render | test image, per scale).
    let (status, _, metrics) = get(addr, "/api/metrics");
    assert_eq!(status, 200);
    let metrics: serde_json::Value = serde_json::from_slice(&metrics).unwrap();
    // Rows are named by step index, as in metrics.csv.
    assert_eq!(metrics["step"].as_array().unwrap().last().unwrap(), 299);
    let val_steps: Vec<u64> = metrics["val"].as_array().unwrap().iter().map(|v| v[0].as_u64().unwrap()).collect();
    assert_eq!(val_steps, [149, 299]);
    let (status, ty, png) = get(addr, "/api/val/0");
    assert_eq!((status, ty.as_str()), (200, "image/png"));
    assert_eq!(png_size(&png), (64, 32), "the 32 px test view beside its render");
    assert_eq!(get(addr, "/api/val/9").0, 404, "a scale the run does not have");

    // Refusals: 4xx with a reason, and the server keeps serving.
    for (path, code, why) in [
        ("/nowhere", 404, "no such page"),
        ("/api/render?width=8&height=8&fov=0.7", 400, "no c2w"),
        ("/api/render?c2w=1,2,3&width=8&height=8&fov=0.7", 400, "12 finite numbers"),
        (&format!("/api/render?{}", query(&info, 100_000, 8)), 400, "width must be 1 to 512"),
        (&format!("/api/stream?{}", query(&info, 100_000, 8)), 400, "width must be 1 to 1024"),
        (&format!("/api/render?{}", query(&info, 8, 8)).replace("c2w=", "c2w=NaN,"), 400, "c2w"),
        (&format!("/api/stream?{}", query(&info, 8, 0)), 400, "height must be 1 to 1024"),
        ("/api/render?c2w=1,0,0,0,0,1,0,0,0,0,1,4&width=8&height=8&fov=9", 400, "fov"),
    ] {
        let (status, _, body) = get(addr, path);
        assert_eq!(status, code, "{path}");
        assert!(String::from_utf8_lossy(&body).contains(why), "{path}: {}", String::from_utf8_lossy(&body));
    }
    let mut s = TcpStream::connect(addr).unwrap();
    write!(s, "POST /api/render HTTP/1.1\r\nHost: {addr}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n").unwrap();
    let mut reply = String::new();
    s.read_to_string(&mut reply).unwrap();
    assert!(reply.starts_with("HTTP/1.1 405"), "{reply}");
    assert_eq!(get(addr, "/api/info").0, 200, "still serving after the refusals");

    // The page in a real browser: `#drive` makes the page drag its own canvas (through the same
    // pointer handlers a mouse uses) once the first frame is in, and ask for the scales.
    let Some(chromium) = common::chromium("the viewer") else { return };
    let url = format!("http://{addr}/?size=128#drive");
    let browse = |extra: &[&str]| {
        std::process::Command::new(chromium)
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--virtual-time-budget=60000",
                "--window-size=1000,900",
            ])
            .args(extra)
            .arg(&url)
            .output()
            .unwrap()
    };
    let dom = String::from_utf8_lossy(&browse(&["--dump-dom"]).stdout).to_string();
    let canvas = dom.lines().find(|l| l.contains("id=\"view\"")).unwrap_or_else(|| panic!("no canvas in {dom}"));
    let attr = |name: &str| -> i64 {
        let at = canvas.find(&format!("{name}=\"")).unwrap_or_else(|| panic!("no {name} in {canvas}")) + name.len() + 2;
        canvas[at..].split('"').next().unwrap().parse().unwrap()
    };
    let (frames, moved_at, colours) = (attr("data-frames"), attr("data-moved-at"), attr("data-colours"));
    assert!(moved_at >= 1, "the camera moved after the first frame: {canvas}");
    assert!(frames > moved_at, "a new frame arrived after the move: {canvas}");
    assert!(colours >= MIN_FRAME_COLOURS as i64, "the new frame is not blank: {canvas}");
    assert_eq!(attr("data-level"), 0, "the view refined to full size once the camera rested: {canvas}");
    assert!(dom.contains("data-loaded=\"4\""), "the four scales loaded: {dom}");
    assert!(dom.contains("src=\"/api/val/0?step=299\""), "the latest validation render is shown: {dom}");
    // The view before and after the drag, added to a path: a camera file render reads, whose
    // two keys differ, at the canvas's size.
    let link = dom.lines().find(|l| l.contains("id=\"keys\"")).unwrap_or_else(|| panic!("no path link in {dom}"));
    assert!(link.contains("data-keys=\"2\"") && link.contains("(2 views)"), "{link}");
    let href = link.split("href=\"data:application/json,").nth(1).unwrap().split('"').next().unwrap();
    let cameras = dir.path().join("cameras.json");
    std::fs::write(&cameras, percent_decoded(&href.replace("&amp;", "&"))).unwrap();
    let file: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&cameras).unwrap()).unwrap();
    let keys = file["frames"].as_array().unwrap();
    assert_eq!(keys.len(), 2, "{file}");
    assert_ne!(keys[0]["transform_matrix"], keys[1]["transform_matrix"], "the drag moved the camera");
    assert_eq!((keys[0]["w"].as_u64(), keys[0]["h"].as_u64()), (Some(128), Some(128)), "{file}");
    let tour = dir.path().join("tour");
    let c = cameras.to_str().unwrap();
    run_ok(&[
        "render",
        "--run",
        r,
        "--out",
        tour.to_str().unwrap(),
        "--cameras",
        c,
        "--frames",
        "3",
        "--backend",
        "cpu",
    ]);
    for i in 0..3 {
        let frame = image::open(tour.join(format!("frame_{i:04}.png"))).unwrap().to_rgb8();
        assert_eq!(frame.dimensions(), (128, 128));
    }

    let shot = dir.path().join("viewer.png");
    let out = browse(&[&format!("--screenshot={}", shot.display())]);
    assert!(shot.is_file(), "no screenshot: {}", String::from_utf8_lossy(&out.stderr));
    let img = image::open(&shot).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (1000, 900));
    assert!(distinct_colours(&img) > 50, "the screenshot is blank");
    // The viewer guide's picture is this screenshot.
    if let Ok(keep) = std::env::var("MIPNERF_VIEWER_SCREENSHOT") {
        std::fs::copy(&shot, keep).unwrap();
    }
}

#[test]
fn train_view_serves_the_run_while_it_trains() {
    let dir = tempfile::tempdir().unwrap();
    let data = common::small_demo_scene(dir.path(), 4);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    let server = start(&[
        "train",
        "--data",
        d,
        "--out",
        r,
        "--steps",
        "1000000",
        "--batch-rays",
        "64",
        "--backend",
        "cpu",
        "--checkpoint-every",
        "20",
        "--view",
        "--view-port",
        "0",
        "--quiet",
    ]);
    let addr = server.addr.clone();
    let t = Instant::now();
    while !run.join("checkpoint.safetensors").is_file() {
        assert!(t.elapsed() < Duration::from_secs(120), "no checkpoint");
        std::thread::sleep(Duration::from_millis(100));
    }
    let (status, _, info) = get(&addr, "/api/info");
    assert_eq!(status, 200);
    let info: serde_json::Value = serde_json::from_slice(&info).unwrap();
    let step = |png_query: &str| -> u64 {
        let (status, _, sse) = get(&addr, &format!("/api/stream?{png_query}"));
        assert_eq!(status, 200);
        let sse = String::from_utf8(sse).unwrap();
        let last = sse.lines().filter_map(|l| l.strip_prefix("data: ")).rfind(|d| *d != "{}").unwrap().to_string();
        serde_json::from_str::<serde_json::Value>(&last).unwrap()["step"].as_u64().unwrap()
    };
    let q = query(&info, 16, 16);
    let first = step(&q);
    assert!(first >= 20);
    // A later checkpoint is picked up: the model is reloaded.
    let t = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(300));
        if step(&q) > first {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(120), "the model was not reloaded");
    }
    let metrics = || -> serde_json::Value {
        let (status, _, metrics) = get(&addr, "/api/metrics");
        assert_eq!(status, 200);
        serde_json::from_slice(&metrics).unwrap()
    };
    let m = metrics();
    assert!(!m["loss"].as_array().unwrap().is_empty());
    // The page re-renders a resting view when the checkpoint's time changes.
    let t = Instant::now();
    while metrics()["checkpoint"] == m["checkpoint"] {
        assert!(m["checkpoint"].as_u64().is_some() && t.elapsed() < Duration::from_secs(120), "{m}");
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn the_viewer_refuses_a_missing_run_and_a_busy_port_and_says_when_it_is_reachable_from_outside() {
    let dir = tempfile::tempdir().unwrap();
    let out = common::mipnerf(&["view", "--run", dir.path().join("none").to_str().unwrap(), "--port", "0"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("none"), "names the run: {err}");
    // A run it cannot serve gets no URL: the run is read before the server says where it is.
    assert!(!String::from_utf8_lossy(&out.stdout).contains("http://"), "a URL for nothing");

    let data = common::small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    run_ok(&["train", "--data", d, "--out", r, "--steps", "2", "--batch-rays", "16", "--backend", "cpu", "--quiet"]);
    let broken = dir.path().join("broken");
    common::copy_dir(&run, &broken);
    let config = broken.join("config.toml");
    let text = std::fs::read_to_string(&config).unwrap();
    std::fs::write(&config, text + "\ngarbage = [\n").unwrap();
    let out = common::mipnerf(&["view", "--run", broken.to_str().unwrap(), "--port", "0"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("config.toml"), "names the configuration: {err}");
    assert!(!String::from_utf8_lossy(&out.stdout).contains("http://"), "a URL for a run it cannot serve");
    let held = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = held.local_addr().unwrap().port().to_string();
    let out = common::mipnerf(&["view", "--run", r, "--port", &port]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&format!("cannot listen on 127.0.0.1:{port}")), "{err}");

    let mut open = common::command()
        .args(["view", "--run", r, "--port", "0", "--host", "0.0.0.0"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(open.stderr.take().unwrap()).read_line(&mut line).unwrap();
    let _ = open.kill();
    let _ = open.wait();
    assert!(line.contains("reachable from other machines"), "{line}");
}

/// `mipnerf view` of a 2-step run of a 16 px demo scene (the folder is kept while the server runs).
fn viewer_of_a_small_run() -> (tempfile::TempDir, Server) {
    let dir = tempfile::tempdir().unwrap();
    let data = common::small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    let (d, r) = (data.to_str().unwrap(), run.to_str().unwrap());
    run_ok(&["train", "--data", d, "--out", r, "--steps", "2", "--batch-rays", "16", "--backend", "cpu", "--quiet"]);
    let server = start(&["view", "--run", r, "--port", "0"]);
    (dir, server)
}

/// DNS rebinding and other sites' pages: a Host that is not the viewer's, an Origin or a
/// Sec-Fetch-Site of another site are refused (403), and the info names no absolute path; an
/// invalid camera is the request's fault (400); a still is capped in size, and a stream (the
/// camera moved) takes the renderer from a still at once instead of waiting behind it.
#[test]
fn the_viewer_answers_only_its_own_pages_and_a_moving_camera_never_waits_behind_stills() {
    let (dir, server) = viewer_of_a_small_run();
    let addr = server.addr.as_str();
    let port = addr.rsplit(':').next().unwrap();
    for host in ["attacker.example", &format!("attacker.example:{port}"), "127.0.0.1:1", "localhost.evil:80"] {
        let (status, _, body) = get_with(addr, "/api/info", &format!("Host: {host}\r\n"));
        assert_eq!(status, 403, "Host {host}: {}", String::from_utf8_lossy(&body));
    }
    let (status, _, _) = get_with(addr, "/api/info", "");
    assert_eq!(status, 403, "no Host header");
    for host in [format!("localhost:{port}"), format!("[::1]:{port}"), "127.0.0.1".to_string()] {
        assert_eq!(get_with(addr, "/", &format!("Host: {host}\r\n")).0, 200, "Host {host}");
    }
    let own = format!("Host: {addr}\r\n");
    let (status, _, _) = get_with(addr, "/api/info", &format!("{own}Origin: http://attacker.example\r\n"));
    assert_eq!(status, 403, "another site's Origin");
    let (status, _, _) = get_with(addr, "/api/info", &format!("{own}Origin: http://{addr}\r\n"));
    assert_eq!(status, 200, "the page's own Origin");
    let (status, _, _) = get_with(addr, "/api/metrics", &format!("{own}Sec-Fetch-Site: cross-site\r\n"));
    assert_eq!(status, 403, "an <img> or fetch from another site");
    let (status, _, _) = get_with(addr, "/api/metrics", &format!("{own}Sec-Fetch-Site: same-origin\r\n"));
    assert_eq!(status, 200);
    let (_, _, info) = get(addr, "/api/info");
    let info: serde_json::Value = serde_json::from_slice(&info).unwrap();
    assert_eq!(info["run"], "run", "the run's folder name, not where it lies: {info}");
    assert!(!String::from_utf8_lossy(&serde_json::to_vec(&info).unwrap()).contains(dir.path().to_str().unwrap()));

    // An invalid camera is a 400; a still larger than 512 px is refused.
    let zero = "c2w=0,0,0,0,0,0,0,0,0,0,0,0&width=8&height=8&fov=0.7";
    let (status, _, body) = get(addr, &format!("/api/render?{zero}"));
    assert_eq!(status, 400, "{}", String::from_utf8_lossy(&body));
    assert!(String::from_utf8_lossy(&body).contains("invalid camera"));
    let (status, _, _) = get(addr, &format!("/api/render?{}", query(&info, 1024, 1024)));
    assert_eq!(status, 400);

    // A 512 px still is under way; a stream's first (1/8) frame comes without waiting for it,
    // and the still is answered 503 (ask again).
    let still = {
        let (addr, q) = (addr.to_string(), query(&info, 512, 512));
        std::thread::spawn(move || {
            let t = Instant::now();
            let (status, _, _) = get(&addr, &format!("/api/render?{q}"));
            (status, t.elapsed())
        })
    };
    std::thread::sleep(Duration::from_millis(300));
    let t = Instant::now();
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    write!(s, "GET /api/stream?{} HTTP/1.1\r\nHost: {addr}\r\n\r\n", query(&info, 256, 256)).unwrap();
    let mut reader = BufReader::new(s);
    let mut line = String::new();
    while !line.starts_with("data: ") {
        line.clear();
        assert!(reader.read_line(&mut line).unwrap() > 0, "the stream ended without a frame");
    }
    let first_frame = t.elapsed();
    let (status, took) = still.join().unwrap();
    assert_eq!(status, 503, "the still gave way to the stream (it ran {took:?}; the frame came after {first_frame:?})");
}

/// A request head larger than 16 KiB is answered 431 without being held (a 100 MB header once
/// took the process from 13 MB to 235 MB), and the server goes on serving; a still whose client
/// has gone is dropped, so the next frame does not wait for it.
#[test]
fn the_viewer_bounds_what_a_client_can_make_it_hold_and_drops_frames_nobody_reads() {
    let (_dir, server) = viewer_of_a_small_run();
    let addr = server.addr.as_str();
    // 1 MB of header: refused after 16 KiB.
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    let head = format!("GET /api/info HTTP/1.1\r\nHost: {addr}\r\nX-Big: {}\r\n\r\n", "a".repeat(1 << 20));
    let _ = s.write_all(head.as_bytes());
    let mut reply = Vec::new();
    let _ = s.read_to_end(&mut reply);
    assert!(String::from_utf8_lossy(&reply).starts_with("HTTP/1.1 431"), "{}", String::from_utf8_lossy(&reply));
    let (status, _, info) = get(addr, "/api/info");
    assert_eq!(status, 200, "still serving");
    let info: serde_json::Value = serde_json::from_slice(&info).unwrap();

    // How long a 512 px still takes here, whole.
    let t = Instant::now();
    assert_eq!(get(addr, &format!("/api/render?{}", query(&info, 512, 512))).0, 200);
    let whole = t.elapsed();
    // The same still again, its client gone after 200 ms: an 8 px still asked next comes long
    // before the big one would have been done.
    let mut s = TcpStream::connect(addr).unwrap();
    write!(s, "GET /api/render?{} HTTP/1.1\r\nHost: {addr}\r\n\r\n", query(&info, 512, 512)).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    drop(s);
    let t = Instant::now();
    assert_eq!(get(addr, &format!("/api/render?{}", query(&info, 8, 8))).0, 200);
    let next = t.elapsed();
    assert!(next < whole / 2, "the next frame waited {next:?} for a still nobody reads (a whole one takes {whole:?})");
}

/// A forward-facing capture in the viewer: the frame keeps the photos' aspect ratio (not a
/// square), and the camera stays where the photos were: the page's own drag (`#drive`) swings
/// the orbit further than the capture's cameras go, and the page holds it back.
#[test]
fn a_forward_facing_capture_keeps_its_aspect_and_its_camera_stays_where_the_photos_were() {
    let dir = tempfile::tempdir().unwrap();
    let (run, _) = common::train_fern_fast(dir.path(), "30", &["--quiet"]);
    let r = run.to_str().unwrap();
    let server = start(&["view", "--run", r, "--port", "0"]);
    let addr = server.addr.as_str();
    let (status, _, info) = get(addr, "/api/info");
    assert_eq!(status, 200);
    let info: serde_json::Value = serde_json::from_slice(&info).unwrap();
    assert_eq!(info["forward_facing"], true, "{info}");
    assert!((info["aspect"].as_f64().unwrap() - 63.0 / 47.0).abs() < 1e-9, "{info}");
    let Some(chromium) = common::chromium("the forward-facing viewer") else { return };
    let out = std::process::Command::new(chromium)
        .args(["--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=60000", "--dump-dom"])
        .arg(format!("http://{addr}/?size=126#drive"))
        .output()
        .unwrap();
    let dom = String::from_utf8_lossy(&out.stdout).to_string();
    let canvas = dom.lines().find(|l| l.contains("id=\"view\"")).unwrap_or_else(|| panic!("no canvas in {dom}"));
    let attr = |name: &str| -> Option<i64> {
        let at = canvas.find(&format!("{name}=\""))? + name.len() + 2;
        canvas[at..].split('"').next()?.parse().ok()
    };
    assert_eq!((attr("width"), attr("height")), (Some(126), Some(94)), "63:47 at 126 px wide: {canvas}");
    assert!(attr("data-moved-at").unwrap_or(0) >= 1, "the camera moved after the first frame: {canvas}");
    assert!(attr("data-clamped").unwrap_or(0) >= 1, "the drag past the capture was held back: {canvas}");
    assert!(attr("data-frames").unwrap_or(0) > attr("data-moved-at").unwrap_or(0), "a frame after the move: {canvas}");
}

/// The viewer serves a run of the Tri-Mip field as any other: a still and the coarse-to-fine
/// stream of a trained model that is not blank.
#[test]
fn the_viewer_serves_a_run_of_the_tri_mip_field() {
    let dir = tempfile::tempdir().unwrap();
    let data = common::demo_scene(dir.path(), 32, 8);
    let run = dir.path().join("run");
    let cfg = dir.path().join("planes.toml");
    std::fs::write(&cfg, "tri_mip_resolution = 64\n").unwrap();
    let (d, r, c) = (data.to_str().unwrap(), run.to_str().unwrap(), cfg.to_str().unwrap());
    let train = ["train", "--data", d, "--out", r, "--preset", "fast", "--field", "tri-mip", "--config", c];
    run_ok(&[&train[..], &["--steps", "150", "--backend", "cpu", "--quiet"]].concat());
    let server = start(&["view", "--run", r, "--port", "0"]);
    let addr = server.addr.as_str();
    let (status, _, info) = get(addr, "/api/info");
    assert_eq!(status, 200);
    let info: serde_json::Value = serde_json::from_slice(&info).unwrap();
    let (status, ty, png) = get(addr, &format!("/api/render?{}", query(&info, 24, 20)));
    assert_eq!((status, ty.as_str()), (200, "image/png"));
    let frame = image::load_from_memory(&png).unwrap().to_rgb8();
    assert!(distinct_colours(&frame) >= MIN_FRAME_COLOURS, "a blank frame: {} colours", distinct_colours(&frame));
    let (status, ty, sse) = get(addr, &format!("/api/stream?{}", query(&info, 32, 32)));
    assert_eq!((status, ty.as_str()), (200, "text/event-stream"));
    let sse = String::from_utf8(sse).unwrap();
    let frames = sse.lines().filter(|l| l.starts_with("data: ") && *l != "data: {}").count();
    assert!(frames >= 2, "the coarse-to-fine stream sends its frames: {sse}");
}

/// A Tri-Mip run trained on the GPU, served by the viewer rendering on the GPU: a still of the
/// size asked for, not blank.
#[test]
fn the_viewer_serves_a_tri_mip_run_rendered_on_the_gpu() {
    if mipnerf_gpu::test_support::context_or_skip("the_viewer_serves_a_tri_mip_run_rendered_on_the_gpu").is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let data = common::small_demo_scene(dir.path(), 2);
    let run = dir.path().join("run");
    let cfg = dir.path().join("small.toml");
    std::fs::write(&cfg, "tri_mip_resolution = 32\n").unwrap();
    let (d, r, c) = (data.to_str().unwrap(), run.to_str().unwrap(), cfg.to_str().unwrap());
    let train = ["train", "--data", d, "--out", r, "--steps", "20", "--batch-rays", "256", "--preset", "fast"];
    run_ok(&[&train[..], &["--field", "tri-mip", "--config", c, "--backend", "gpu", "--quiet"]].concat());
    let server = start(&["view", "--run", r, "--port", "0", "--backend", "gpu"]);
    let addr = server.addr.as_str();
    let (status, _, info) = get(addr, "/api/info");
    assert_eq!(status, 200);
    let info: serde_json::Value = serde_json::from_slice(&info).unwrap();
    let (status, ty, png) = get(addr, &format!("/api/render?{}", query(&info, 24, 20)));
    assert_eq!((status, ty.as_str()), (200, "image/png"), "{}", String::from_utf8_lossy(&png));
    assert_eq!(png_size(&png), (24, 20));
    let frame = image::load_from_memory(&png).unwrap().to_rgb8();
    assert!(distinct_colours(&frame) > 1, "a blank frame");
}
