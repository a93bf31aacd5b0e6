//! `mipnerf bench --viewer RUN_DIR`: the live viewer measured as a browser uses it, over HTTP on
//! loopback.
//!
//! 1. **Frame latency**: `mipnerf view`'s server for the run, in this process; for each of a
//!    number of camera poses (the run's start pose turned about the world's up axis, as a drag
//!    turns it) a client opens the page's stream and times, from the request, the arrival of each
//!    level (1/8, 1/4, 1/2, full size) and the server's own rendering time of it: with the camera
//!    resting (every pose streamed to full size), then moving (the next pose asked for as soon as
//!    a pose's 1/8 frame arrived, as a drag does, superseding the refinement under way).
//! 2. **Training stall**: the run's configuration trained for a fixed number of steps in a child
//!    `mipnerf train`, twice: alone, then with `--view` while a client streams poses without
//!    pause (five moving, one resting, by turns: the viewer never idle). The stall is the share of
//!    training time lost, `1 - alone / with_viewer`, from the two runs' own `train_seconds.txt`.

use crate::session::Session;
use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use crate::config::Backend;
use crate::view::{self, LEVELS, ViewArgs};

/// What `mipnerf bench --viewer` measures.
#[derive(Clone, Debug)]
pub struct ViewerBenchArgs {
    /// The trained run whose viewer is measured.
    pub run: PathBuf,
    /// Where the frames are rendered.
    pub backend: Backend,
    /// The GPU to open when `backend` is one.
    pub device: mipnerf_gpu::DeviceOptions,
    /// The full frame's side in pixels (the page's default is 512).
    pub size: u32,
    /// Camera poses timed (after one untimed pose that loads the model).
    pub frames: usize,
    /// Training steps of each of the two stall runs (0: no stall measurement).
    pub stall_steps: u64,
}

/// One streamed pose: per level (coarsest first), the time from the request to its arrival and
/// the server's rendering time, in milliseconds.
#[derive(Clone, Debug, Default)]
struct Timed {
    arrived_ms: Vec<f64>,
    render_ms: Vec<f64>,
    sizes: Vec<(u64, u64)>,
}

/// Measures and prints the viewer's tables.
///
/// # Errors
/// An unreadable run, a server that cannot start, or a failing child run.
pub fn bench(a: &ViewerBenchArgs, session: &Session) -> Result<()> {
    anyhow::ensure!((8..=view::MAX_SIDE).contains(&a.size), "--viewer-size must be 8 to {}", view::MAX_SIDE);
    anyhow::ensure!(a.frames > 0, "--viewer-frames must be positive");
    let settings = crate::run::read_config(&a.run)?;
    anyhow::ensure!(
        crate::run_dir::RunDir::new(&a.run).checkpoint().is_file(),
        "{}: no checkpoint; train the run first",
        a.run.display()
    );
    println!(
        "viewer of {} ({} preset, {} model), frames {s}x{s} on {:?}, {} threads",
        a.run.display(),
        settings.preset.map(|p| format!("{p:?}").to_lowercase()).unwrap_or_default(),
        settings.model.map(|m| format!("{m:?}").to_lowercase()).unwrap_or_default(),
        a.backend,
        rayon::current_num_threads(),
        s = a.size
    );
    let args = ViewArgs {
        run: a.run.clone(),
        host: "127.0.0.1".into(),
        port: 0,
        backend: a.backend,
        share: None,
        device: a.device.clone(),
        session: session.clone(),
    };
    let run = view::ViewedRun::open(&args.run)?;
    let (server, url) = view::bind(&args)?;
    let addr = url.trim_start_matches("http://").trim_end_matches('/').to_string();
    std::thread::spawn(move || view::run_server(server, &args, run));
    let info = Info::get(&addr)?;
    let _ = stream(&addr, &info.query(0.0, a.size), ALL)?; // loads the model
    let mut resting = Vec::new();
    for k in 0..a.frames {
        resting.push(stream(&addr, &info.query(0.2 * (k + 1) as f64, a.size), ALL)?);
    }
    let mut moving = Vec::new();
    for k in 0..a.frames {
        moving.push(stream(&addr, &info.query(-0.2 * (k + 1) as f64, a.size), 1)?);
    }
    println!();
    println!(
        "frame latency, `mipnerf view` alone: {} poses, the camera turned 0.2 rad about up between them; \
         resting (each pose streamed to full size):",
        a.frames
    );
    table(&resting);
    println!();
    println!("moving (the next pose asked for as soon as a pose's 1/8 frame arrived, superseding its refinement):");
    table(&moving);

    if a.stall_steps > 0 {
        stall(a)?;
    }
    Ok(())
}

/// Prints the latency table: per level, the median and largest time to arrive and to render.
fn table(timed: &[Timed]) {
    println!("| level | frame | arrives after (median ms) | (max ms) | rendered in (median ms) |");
    println!("|---|---|---|---|---|");
    for l in 0..LEVELS as usize {
        let of =
            |f: fn(&Timed) -> &Vec<f64>| -> Vec<f64> { timed.iter().filter_map(|t| f(t).get(l).copied()).collect() };
        let (arrived, rendered) = (of(|t| &t.arrived_ms), of(|t| &t.render_ms));
        let Some((w, h)) = timed.iter().find_map(|t| t.sizes.get(l).copied()) else { continue };
        let name =
            if l + 1 == LEVELS as usize { "full".to_string() } else { format!("1/{}", 1 << (LEVELS as usize - 1 - l)) };
        println!(
            "| {name} | {w}x{h} | {:.0} | {:.0} | {:.0} |",
            median(&arrived),
            arrived.iter().copied().fold(0.0, f64::max),
            median(&rendered)
        );
    }
}

fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    if v.is_empty() { f64::NAN } else { v[v.len() / 2] }
}

/// The run's start pose, field of view and up axis, as the page reads them.
struct Info {
    start: [[f64; 4]; 3],
    fov: f64,
    up: [f64; 3],
}

impl Info {
    fn get(addr: &str) -> Result<Self> {
        let mut s = TcpStream::connect(addr).with_context(|| format!("connecting to the viewer at {addr}"))?;
        write!(s, "GET /api/info HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n")?;
        let mut text = String::new();
        std::io::Read::read_to_string(&mut s, &mut text)?;
        let body = text.split_once("\r\n\r\n").map(|(_, b)| b).context("the viewer's /api/info had no body")?;
        // The JSON object is what lies between the outer braces of the body.
        let json = &body[body.find('{').context("no JSON")?..=body.rfind('}').context("no JSON")?];
        let v: serde_json::Value = serde_json::from_str(json).context("the viewer's /api/info")?;
        let num = |x: &serde_json::Value| x.as_f64().context("a number");
        let row = |r: &serde_json::Value| -> Result<[f64; 4]> {
            let r = r.as_array().context("a row")?;
            Ok([num(&r[0])?, num(&r[1])?, num(&r[2])?, num(&r[3])?])
        };
        let start = v["start"].as_array().context("start")?;
        let up = v["up"].as_array().context("up")?;
        Ok(Self {
            start: [row(&start[0])?, row(&start[1])?, row(&start[2])?],
            fov: num(&v["fov"])?,
            up: [num(&up[0])?, num(&up[1])?, num(&up[2])?],
        })
    }

    /// The stream query for the start pose turned by `angle` radians about the up axis through
    /// the origin.
    fn query(&self, angle: f64, size: u32) -> String {
        let (u, (s, c)) = (self.up, angle.sin_cos());
        let rot: [[f64; 3]; 3] = std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                let cross = match (i, j) {
                    (0, 1) => -u[2],
                    (0, 2) => u[1],
                    (1, 0) => u[2],
                    (1, 2) => -u[0],
                    (2, 0) => -u[1],
                    (2, 1) => u[0],
                    _ => 0.0,
                };
                (if i == j { c } else { 0.0 }) + s * cross + (1.0 - c) * u[i] * u[j]
            })
        });
        let pose: Vec<String> = (0..3)
            .flat_map(|i| (0..4).map(move |j| (i, j)))
            .map(|(i, j)| (0..3).map(|k| rot[i][k] * self.start[k][j]).sum::<f64>())
            .map(|x| format!("{x:.6}"))
            .collect();
        format!("c2w={}&width={size}&height={size}&fov={}", pose.join(","), self.fov)
    }
}

/// Every level of a stream.
const ALL: usize = LEVELS as usize;

/// Streams one pose and times its first `levels` levels, then closes the stream. A stream that
/// fails (no checkpoint yet) is an error.
fn stream(addr: &str, query: &str, levels: usize) -> Result<Timed> {
    let t = Instant::now();
    let mut s = TcpStream::connect(addr).with_context(|| format!("connecting to the viewer at {addr}"))?;
    s.set_read_timeout(Some(Duration::from_secs(600)))?;
    write!(s, "GET /api/stream?{query} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n")?;
    let mut timed = Timed::default();
    let mut failed = false;
    for line in BufReader::new(s).lines() {
        let line = line?;
        if line.starts_with("event: failed") {
            failed = true;
        } else if let Some(data) = line.strip_prefix("data: ") {
            if failed {
                bail!("the viewer could not render: {data}");
            }
            if data == "{}" {
                break;
            }
            let v: serde_json::Value = serde_json::from_str(data).context("a streamed frame")?;
            timed.arrived_ms.push(t.elapsed().as_secs_f64() * 1000.0);
            timed.render_ms.push(v["ms"].as_f64().unwrap_or(f64::NAN));
            timed.sizes.push((v["width"].as_u64().unwrap_or(0), v["height"].as_u64().unwrap_or(0)));
            if timed.arrived_ms.len() == levels {
                break;
            }
        }
    }
    anyhow::ensure!(timed.arrived_ms.len() == levels, "the stream ended after {} frames", timed.arrived_ms.len());
    Ok(timed)
}

/// The run's settings for `steps` steps, without a time budget or validation, a checkpoint
/// every 50 steps (what the viewer reloads), as a config file in `dir`.
fn stall_config(run: &Path, dir: &Path, steps: u64) -> Result<PathBuf> {
    let path = crate::run_dir::RunDir::new(run).config();
    let text = mipnerf_core::io::read_regular_text(&path, mipnerf_core::io::cap::SETTINGS)
        .with_context(|| format!("reading {}", path.display()))?;
    let mut t: toml::Table = toml::from_str(&text).with_context(|| format!("{}: not TOML", path.display()))?;
    t.remove("time_budget");
    t.insert("steps".into(), toml::Value::Integer(i64::try_from(steps)?));
    t.insert("checkpoint_every".into(), toml::Value::Integer(50));
    t.insert("val_every".into(), toml::Value::Integer(0));
    let out = dir.join("stall.toml");
    std::fs::write(&out, toml::to_string(&t)?).with_context(|| format!("writing {}", out.display()))?;
    Ok(out)
}

/// Trains the run's configuration alone and beside a streaming viewer; prints the stall.
fn stall(a: &ViewerBenchArgs) -> Result<()> {
    let dir = tempfile::tempdir().context("a temporary folder for the stall runs")?;
    let config = stall_config(&a.run, dir.path(), a.stall_steps)?;
    let exe = std::env::current_exe().context("this program's path")?;
    let train = |out: &Path, view: bool| {
        let mut c = std::process::Command::new(&exe);
        c.args(["train", "--quiet", "--config"]).arg(&config).arg("--out").arg(out);
        if view {
            c.args(["--view", "--view-port", "0"]);
        }
        c.stdout(Stdio::piped()).stderr(Stdio::inherit());
        c
    };
    let seconds = |out: &Path| {
        crate::run::train_seconds(out)?.with_context(|| format!("{}: no train_seconds.txt", out.display()))
    };

    let alone = dir.path().join("alone");
    let status = train(&alone, false).status().context("starting mipnerf train")?;
    anyhow::ensure!(status.success(), "the run without the viewer failed");
    let t_alone = seconds(&alone)?;

    let beside = dir.path().join("beside");
    let mut child = train(&beside, true).spawn().context("starting mipnerf train --view")?;
    let mut lines = BufReader::new(child.stdout.take().context("the child's output")?).lines();
    let addr = loop {
        let line = lines.next().context("train --view printed no URL")??;
        if let Some(rest) = line.strip_prefix("view: http://") {
            break rest.split('/').next().unwrap_or_default().to_string();
        }
    };
    std::thread::spawn(move || lines.for_each(drop));
    let done = Arc::new(AtomicBool::new(false));
    let client = {
        let (done, size, addr) = (Arc::clone(&done), a.size, addr.clone());
        std::thread::spawn(move || -> Vec<Timed> {
            let mut timed = Vec::new();
            let mut info = None;
            let mut k = 0usize;
            while !done.load(Ordering::Relaxed) {
                if info.is_none() {
                    info = Info::get(&addr).ok();
                }
                // Moving and resting by turns: 5 poses superseded after their 1/8 frame, then
                // one streamed to full size.
                let levels = if k % 6 == 5 { ALL } else { 1 };
                match info.as_ref().map(|i| stream(&addr, &i.query(0.2 * k as f64, size), levels)) {
                    Some(Ok(t)) => {
                        timed.push(t);
                        k += 1;
                    }
                    // No checkpoint yet, or training ended.
                    _ => std::thread::sleep(Duration::from_millis(100)),
                }
            }
            timed
        })
    };
    let status = child.wait().context("waiting for mipnerf train --view")?;
    done.store(true, Ordering::Relaxed);
    let timed = client.join().map_err(|_| anyhow::anyhow!("the client thread panicked"))?;
    anyhow::ensure!(status.success(), "the run with the viewer failed");
    let t_beside = seconds(&beside)?;
    println!();
    println!(
        "training stall: {} steps of the run's configuration (checkpoint every 50 steps), alone, then with \
         `train --view` while a client streamed {} poses without pause, by turns five moving (superseded after \
         their 1/8 frame) and one resting (streamed to full size) (rendering capped at {:.0}% of the time):",
        a.stall_steps,
        timed.len(),
        view::SHARE_BESIDE_TRAINING * 100.0
    );
    println!("| training | seconds | steps/s |");
    println!("|---|---|---|");
    let steps = a.stall_steps as f64;
    println!("| alone | {t_alone:.1} | {:.2} |", steps / t_alone);
    println!("| beside a streaming viewer | {t_beside:.1} | {:.2} |", steps / t_beside);
    println!("stall: {:.1}% of training time", 100.0 * (1.0 - t_alone / t_beside));
    println!();
    println!("frame latency beside training ({} poses):", timed.len());
    table(&timed);
    Ok(())
}
