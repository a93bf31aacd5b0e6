//! `mipnerf view` (and `train --view`): a local web page that shows a run as it trains.
//!
//! One page with no build step and no external assets (`assets/view.html`): an orbit camera whose
//! view is rendered coarse to fine while it rests (server-sent events, one PNG per level), the
//! training and test curves from `metrics.csv`, and the same view at the four scales of
//! Mip-NeRF side by side. The run's latest checkpoint is reloaded whenever a new one lands.
//!
//! The server is `http.rs` (requests parsed by `httparse`) with a thread per connection: the
//! viewer serves one person and renders one frame at a time, so threads suffice and no async
//! runtime is pulled in; owning the connection bounds what a client can make it hold and tells
//! when a client has gone, so its frame is dropped. Rendering happens on
//! one thread that owns the backend (backends are not `Send`); requests queue for it.

use crate::session::Session;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime};

use anyhow::{Context, Result, bail};
use base64::Engine;
use mipnerf_core::backend::ImageSpec;
use mipnerf_core::camera::Camera;
use mipnerf_core::dataset::Split;
use mipnerf_core::model::Levels;

use crate::config::{Backend, TrainSettings};
use crate::metrics_csv::MetricsRows;
use crate::run::{RunOn, load_split, open_trained, read_config};
use crate::run_dir::RunDir;

/// The page.
const PAGE: &str = include_str!("../assets/view.html");
/// The largest frame side a stream may ask for.
pub const MAX_SIDE: u32 = 1024;
/// The largest side of a single frame (`/api/render`; the page's scales panel asks for 256 at
/// most): a still is rendered whole, so its cost is bounded here.
pub const MAX_STILL_SIDE: u32 = 512;
/// Stills queued or rendering at once (the page asks for four); one more is answered 503.
pub const MAX_QUEUED_STILLS: usize = 4;
/// Refinement levels of a streamed view: 1/8, 1/4, 1/2 and full size.
pub const LEVELS: u32 = 4;
/// Beside training (`train --view`), the most of the wall-clock time the viewer may spend
/// rendering: after a band of rows that took `t`, the renderer owes a rest of
/// `t * (1 / share - 1)` (see [`REST_ALLOWANCE`]), so that a client streaming without pause
/// takes at most this share of the CPU's time from training (measured by
/// `mipnerf bench --viewer`). `mipnerf view` alone renders without rests.
pub const SHARE_BESIDE_TRAINING: f64 = 0.25;

/// What `mipnerf view` serves.
#[derive(Clone, Debug)]
pub struct ViewArgs {
    /// The run directory.
    pub run: PathBuf,
    /// Address to bind (loopback unless asked otherwise).
    pub host: String,
    /// Port (0: any free one).
    pub port: u16,
    /// Where frames are rendered.
    pub backend: Backend,
    /// The most of the wall-clock time rendering may take (`None`: all of it).
    pub share: Option<f64>,
    /// The GPU to open when `backend` is one (`--adapter`, `--gpu-memory`).
    pub device: mipnerf_gpu::DeviceOptions,
    /// The invocation's global flags.
    pub session: Session,
}

/// A rendered frame.
struct Frame {
    png: Vec<u8>,
    width: u32,
    height: u32,
    ms: u128,
    step: u64,
}

/// A frame to render: the camera-to-world pose, size and horizontal field of view.
#[derive(Clone, Copy, Debug)]
struct FrameRequest {
    c2w: [[f64; 4]; 3],
    width: u32,
    height: u32,
    fov: f64,
}

/// Who asked for a frame: a level of the page's stream (superseded by the next stream: the
/// camera moved), or a single frame (`/api/render`: the scales panel), always finished.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Stream,
    Still,
}

/// A frame to render, and where its answer goes.
struct Job {
    req: FrameRequest,
    kind: Kind,
    reply: mpsc::Sender<Result<Frame, String>>,
    /// Set when the client that asked has gone: the frame is dropped at the next band.
    cancel: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

/// Pixels rendered between two checks for a newer stream (and, beside training, two rests):
/// the 1/8 level of a 512 px view is one band.
pub const BAND_PIXELS: u32 = 4096;
/// Beside training, the rest the renderer may still owe when it starts the first band of a
/// stream's level: the coarse frame after a camera move is not kept waiting behind the rest of
/// the refinement it superseded, yet a camera that never stops gets at most
/// [`SHARE_BESIDE_TRAINING`] of the time (plus this, once).
pub const REST_ALLOWANCE: Duration = Duration::from_secs(1);
/// What a superseded stream level answers.
const SUPERSEDED: &str = "superseded by a newer view";
/// What a still answers when a stream (the camera moved) takes the renderer from it.
const PREEMPTED: &str = "preempted by the moving view; ask again";
/// What a frame whose client has gone ends with (nobody reads it).
const CLIENT_GONE: &str = "the client has gone";
/// How often a request's thread looks whether its client is still there while its frame renders.
const CLIENT_CHECK: Duration = Duration::from_millis(100);

/// Which `Host` (and `Origin`) names a request may carry: the loopback names (`127.0.0.1`,
/// `localhost`, `[::1]`), with the server's port if any port is given, and the name `--host`
/// gave when it is not a loopback one (any name when it is `0.0.0.0` or `::`, which the user chose
/// knowing that the viewer is then reachable from other machines). A page on another site
/// cannot read the viewer through DNS rebinding (its Host is that site's name) nor make the
/// browser load frames from it (`Origin` or `Sec-Fetch-Site` names another site).
#[derive(Clone, Debug)]
struct HostPolicy {
    port: u16,
    named: Option<String>,
    any: bool,
}

impl HostPolicy {
    fn new(host: &str, port: u16) -> Self {
        let unspecified = host.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_unspecified());
        let loopback = host.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback()) || host == "localhost";
        let named = (!loopback && !unspecified)
            .then(|| if host.contains(':') && !host.starts_with('[') { format!("[{host}]") } else { host.to_string() });
        Self { port, named, any: unspecified }
    }

    fn allows_host(&self, host: &str) -> bool {
        if self.any {
            return true;
        }
        // `name` or `name:port`; an IPv6 name comes in brackets.
        let (name, port) = match host.rfind(':') {
            Some(i) if !host[i..].contains(']') => (&host[..i], Some(&host[i + 1..])),
            _ => (host, None),
        };
        if port.is_some_and(|p| p.parse::<u16>().ok() != Some(self.port)) {
            return false;
        }
        let name = name.to_ascii_lowercase();
        matches!(name.as_str(), "127.0.0.1" | "localhost" | "[::1]")
            || self.named.as_deref().is_some_and(|n| n.eq_ignore_ascii_case(&name))
    }

    /// Why `request` is refused (403), if it is.
    fn refusal(&self, request: &crate::http::Request) -> Option<String> {
        let header = |name: &'static str| request.header(name).map(str::to_string);
        match header("Host") {
            None => return Some("no Host header".into()),
            Some(h) if !self.allows_host(&h) => {
                return Some(format!(
                    "Host {h:?} is not this viewer's address (127.0.0.1, localhost or [::1], port {})",
                    self.port
                ));
            }
            Some(_) => {}
        }
        if let Some(origin) = header("Origin")
            && !origin.strip_prefix("http://").is_some_and(|h| self.allows_host(h))
        {
            return Some(format!("a request from another site (Origin {origin:?})"));
        }
        if let Some(site) = header("Sec-Fetch-Site")
            && !matches!(site.as_str(), "same-origin" | "none")
        {
            return Some(format!("a request from another site (Sec-Fetch-Site: {site})"));
        }
        None
    }
}

/// Reads the run, then starts the server and serves until the process ends; prints the URL
/// once the run has been read, so a run that cannot be served is an error before any URL.
///
/// # Errors
/// An unreadable run, or an address that cannot be bound.
pub fn serve(a: &ViewArgs) -> Result<()> {
    let run = ViewedRun::open(&a.run)?;
    let (server, url) = bind(a)?;
    println!("view: {url} (serving {}; Ctrl-C stops)", a.run.display());
    run_server(server, a, run)
}

/// What the server needs of a run, read before it serves: the run's settings, its
/// `/api/info`, and how its images are made.
pub struct ViewedRun {
    settings: TrainSettings,
    info: String,
    template: ImageSpec,
}

impl ViewedRun {
    /// Reads the run in `run` (its configuration and its training views).
    ///
    /// # Errors
    /// A missing or malformed configuration, or data that cannot be loaded.
    pub fn open(run: &Path) -> Result<Self> {
        let settings = read_config(run)?;
        let train = load_split(&settings, Split::Train)?;
        let info = info_json(run, &settings, &train)?;
        let template = ImageSpec::of_view(&train, 0, crate::render::read_supersample(&settings)?);
        Ok(Self { settings, info, template })
    }
}

/// `train --view`: the viewer of the run in `run_dir` on 127.0.0.1:`port`, in a thread beside
/// training (it starts serving once training has written the run's configuration).
///
/// # Errors
/// A port that cannot be bound.
pub fn beside_training(run_dir: &Path, port: u16, session: &Session) -> Result<()> {
    let args = ViewArgs {
        run: run_dir.to_path_buf(),
        host: "127.0.0.1".into(),
        port,
        backend: Backend::Cpu,
        share: Some(SHARE_BESIDE_TRAINING),
        device: mipnerf_gpu::DeviceOptions::default(),
        session: session.clone(),
    };
    let (server, url) = bind(&args)?;
    println!("view: {url} (the run's latest checkpoint, while it trains)");
    std::thread::Builder::new()
        .name("view server".into())
        .spawn(move || {
            while !RunDir::new(&args.run).config().is_file() {
                std::thread::sleep(std::time::Duration::from_millis(200));
            }
            if let Err(e) = ViewedRun::open(&args.run).and_then(|run| run_server(server, &args, run)) {
                eprintln!("view: stopped: {e:#}");
            }
        })
        .context("starting the viewer")?;
    Ok(())
}

/// Binds the server, saying where and that only this machine can reach a loopback address.
///
/// # Errors
/// An address that cannot be bound.
pub fn bind(a: &ViewArgs) -> Result<(std::net::TcpListener, String)> {
    let server = crate::http::bind(&a.host, a.port)
        .map_err(|e| anyhow::anyhow!("cannot listen on {}:{}: {e}", a.host, a.port))?;
    let addr = server.local_addr().context("the viewer's address")?;
    if !addr.ip().is_loopback() {
        eprintln!("view: listening on {addr}, reachable from other machines (--host); the default is 127.0.0.1");
    }
    Ok((server, format!("http://{addr}/")))
}

/// Serves `server` for `run` (the run of `a`, read) until the process ends.
///
/// # Errors
/// A render thread that cannot be started.
pub fn run_server(server: std::net::TcpListener, a: &ViewArgs, run: ViewedRun) -> Result<()> {
    let ViewedRun { settings: s, info, template } = run;
    let (tx, rx) = mpsc::channel::<Job>();
    let args = a.clone();
    std::thread::Builder::new()
        .name("view renderer".into())
        .spawn(move || renderer(&args, &s, &template, &rx))
        .context("starting the render thread")?;
    let port = server.local_addr().map_or(a.port, |addr| addr.port());
    let shared = std::sync::Arc::new(Shared {
        info,
        run: a.run.clone(),
        policy: HostPolicy::new(&a.host, port),
        stills: std::sync::atomic::AtomicUsize::new(0),
    });
    for connection in server.incoming() {
        let Ok(connection) = connection else { continue };
        let (tx, shared) = (tx.clone(), std::sync::Arc::clone(&shared));
        std::thread::spawn(move || {
            if let Some(request) = crate::http::read_request(connection) {
                handle(request, &tx, &shared);
            }
        });
    }
    Ok(())
}

/// The render thread: owns the backend, reloads the run's checkpoint when it changes, and
/// renders the frames asked for, one at a time, in bands of rows ([`BAND_PIXELS`]). It drops a
/// stream's level as soon as a newer stream waits (the camera moved), so a moving camera gets
/// its coarse frame within a band. With a share (`ViewArgs::share`, beside training) every band adds
/// `took * (1 / share - 1)` to a rest it owes, and a band starts only once the rest owed is paid
/// down to [`REST_ALLOWANCE`] for the first band of a stream's level (the coarse frame after a
/// move comes at once) or to zero for the others: over any stretch of time rendering takes at
/// most `share` of it, give or take one allowance.
fn renderer(a: &ViewArgs, s: &TrainSettings, template: &ImageSpec, jobs: &mpsc::Receiver<Job>) {
    let run = a.run.as_path();
    let mut loaded: Option<(Box<dyn mipnerf_core::backend::Backend>, u64, Option<SystemTime>)> = None;
    let ckpt = RunDir::new(run).checkpoint();
    let mut waiting = std::collections::VecDeque::new();
    let share = a.share.filter(|s| *s > 0.0 && *s < 1.0);
    // The rest owed, as of `paid_at`: any time not spent rendering pays it, idle time included.
    let (mut owed, mut paid_at) = (Duration::ZERO, Instant::now());
    loop {
        // Streams first: a moving camera's frame never waits behind stills.
        let next = waiting.iter().position(|j: &Job| j.kind == Kind::Stream).or((!waiting.is_empty()).then_some(0));
        let Some(job) = next.and_then(|i| waiting.remove(i)).or_else(|| jobs.recv().ok()) else { return };
        let result = (|| -> Result<Frame> {
            let mtime = std::fs::metadata(&ckpt).and_then(|m| m.modified()).ok();
            if loaded.as_ref().is_none_or(|l| l.2 != mtime) {
                // A checkpoint that is being replaced is renamed into place whole, so a failed
                // load is only a missing one: keep the model we have.
                let on = RunOn { backend: a.backend, precision: None, device: &a.device };
                match open_trained(run, s, on, &a.session) {
                    Ok((be, step, _)) => loaded = Some((be, step, mtime)),
                    Err(e) if loaded.is_none() => return Err(e),
                    Err(_) => {}
                }
            }
            let Some((be, step, _)) = loaded.as_mut() else { bail!("no checkpoint in {}", run.display()) };
            let req = job.req;
            let camera = Camera::from_camera_angle_x(req.width, req.height, req.fov, req.c2w)?;
            let image = ImageSpec { camera, ..template.clone() };
            let mut rgb: Vec<[f32; 3]> = Vec::with_capacity(image.pixels());
            let mut busy = Duration::ZERO;
            // A newer stream supersedes a stream's level, and takes the renderer from a still; a
            // frame whose client has gone is dropped.
            let gone = || job.cancel.load(std::sync::atomic::Ordering::SeqCst);
            let superseded =
                |waiting: &std::collections::VecDeque<Job>| gone() || waiting.iter().any(|j| j.kind == Kind::Stream);
            let stop = || {
                if gone() {
                    CLIENT_GONE
                } else if job.kind == Kind::Stream {
                    SUPERSEDED
                } else {
                    PREEMPTED
                }
            };
            for (i, (y0, y1)) in bands(req.width, req.height).into_iter().enumerate() {
                let allowance = if i == 0 && job.kind == Kind::Stream { REST_ALLOWANCE } else { Duration::ZERO };
                // Rest what is owed beyond the allowance, listening for newer requests.
                loop {
                    owed = owed.saturating_sub(paid_at.elapsed());
                    paid_at = Instant::now();
                    if owed <= allowance {
                        break;
                    }
                    if let Ok(j) = jobs.recv_timeout(owed - allowance) {
                        waiting.push_back(j);
                    }
                    if superseded(&waiting) {
                        bail!(stop());
                    }
                }
                let t = Instant::now();
                let (band, extra) = band(&image, y0, y1);
                let out = be.render(&band, Levels::Last)?;
                let keep = (y1 - y0) as usize * req.width as usize;
                debug_assert_eq!(out.fine.len(), keep + extra);
                rgb.extend(out.fine.iter().take(keep).map(|o| o.rgb));
                let took = t.elapsed();
                busy += took;
                if let Some(share) = share {
                    owed += took.mul_f64(1.0 / share - 1.0);
                }
                paid_at = Instant::now();
                waiting.extend(jobs.try_iter());
                if y1 < req.height && superseded(&waiting) {
                    bail!(stop());
                }
            }
            let mut png = Vec::new();
            image::codecs::png::PngEncoder::new(&mut png)
                .write_image(&crate::images::rgb_to_png(&rgb), req.width, req.height, image::ExtendedColorType::Rgb8)
                .context("encoding the frame")?;
            Ok(Frame { png, width: req.width, height: req.height, ms: busy.as_millis(), step: *step })
        })();
        let _ = job.reply.send(result.map_err(|e| format!("{e:#}")));
    }
}

/// The bands of rows `[y0, y1)` a `width` x `height` frame is rendered in: about
/// [`BAND_PIXELS`] each, and never fewer than 3 rows (see [`band`]).
fn bands(width: u32, height: u32) -> Vec<(u32, u32)> {
    let rows = (BAND_PIXELS / width.max(1)).max(3);
    let mut out: Vec<(u32, u32)> = (0..height).step_by(rows as usize).map(|y0| (y0, (y0 + rows).min(height))).collect();
    // A last band under 3 rows joins the one before it.
    if out.len() > 1 && out.last().is_some_and(|b| b.1 - b.0 < 3) {
        let last = out.pop().unwrap_or_default();
        if let Some(prev) = out.last_mut() {
            prev.1 = last.1;
        }
    }
    out
}

/// Rows `y0..y1` of `image` as an image of their own whose rays are the whole image's for
/// those rows, and how many extra pixels it has at its end. A ray's cone radius is the distance
/// to the ray of the row below (the last row's, that of the two rows above it): so a band that
/// does not end the image takes one row more (`width` extra pixels, dropped), and one that does
/// has at least 3 rows ([`bands`]).
fn band(image: &ImageSpec, y0: u32, y1: u32) -> (ImageSpec, usize) {
    let cam = &image.camera;
    let end = (y1 + 1).min(cam.height);
    let mut pix2cam = cam.pix2cam;
    for row in &mut pix2cam {
        row[2] += row[1] * f64::from(y0);
    }
    let camera = Camera { height: end - y0, pix2cam, ..cam.clone() };
    (ImageSpec { camera, ..image.clone() }, ((end - y1) * cam.width) as usize)
}

use image::ImageEncoder;

/// The run's cameras, field of view, up direction and starting pose, as the page reads them.
fn info_json(run: &Path, s: &TrainSettings, train: &mipnerf_core::dataset::Dataset) -> Result<String> {
    let test = load_split(s, Split::Test).ok();
    let poses = |ds: &mipnerf_core::dataset::Dataset| -> Vec<[[f64; 4]; 3]> {
        ds.views().iter().filter(|v| v.scale == 0).map(|v| v.camera.cam2world).collect()
    };
    let train_poses = poses(train);
    let test_poses = test.as_ref().map(poses).unwrap_or_default();
    let first = &train.views()[0].camera;
    let fov = 2.0 * (0.5 * f64::from(first.width) * first.pix2cam[0][0].abs()).atan();
    // World up: the mean of the cameras' up axes.
    let mut up = [0.0f64; 3];
    for p in &train_poses {
        for (k, u) in up.iter_mut().enumerate() {
            *u += p[k][1];
        }
    }
    let n = up.iter().map(|x| x * x).sum::<f64>().sqrt().max(1e-12);
    let start = test_poses.first().or(train_poses.first()).copied().context("no cameras")?;
    // The run's folder name only: the API never tells a page where the run lies on the disk.
    let name = run.canonicalize().ok().and_then(|p| p.file_name().map(|n| n.to_string_lossy().to_string()));
    Ok(serde_json::json!({
        "run": name.unwrap_or_else(|| "run".into()),
        "fov": fov,
        "aspect": f64::from(first.width) / f64::from(first.height.max(1)),
        "forward_facing": train.ndc.is_some(),
        "up": up.map(|x| x / n),
        "start": start,
        "cameras": { "train": train_poses, "test": test_poses },
    })
    .to_string())
}

/// `metrics.csv` as columns (step, loss, psnr, lr), the validation rows, and when the
/// checkpoint last changed.
fn metrics_json(run: &Path) -> String {
    let m = MetricsRows::parse(&std::fs::read_to_string(RunDir::new(run).metrics_csv()).unwrap_or_default());
    let column = |f: fn(&crate::metrics_csv::TrainRow) -> f64| m.train.iter().map(f).collect::<Vec<f64>>();
    let (step, loss, psnr, lr) = (
        m.train.iter().map(|r| r.step).collect::<Vec<u64>>(),
        column(|r| r.loss),
        column(|r| r.psnr),
        column(|r| r.lr),
    );
    let val: Vec<serde_json::Value> = m.val.iter().map(|(s, v)| serde_json::json!([s, v])).collect();
    let scales = m.scales();
    // When the checkpoint last changed (ms since the epoch): the page re-renders a resting view
    // when it does.
    let checkpoint = std::fs::metadata(RunDir::new(run).checkpoint())
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| t.duration_since(SystemTime::UNIX_EPOCH).ok())
        .map(|d| d.as_millis() as u64);
    serde_json::json!({"step": step, "loss": loss, "psnr": psnr, "lr": lr, "val": val,
        "val_scales": vec![0; scales], "checkpoint": checkpoint})
    .to_string()
}

/// A request's query parameters as a frame, or what is wrong with them.
fn parse_frame(query: &str, max_side: u32) -> Result<FrameRequest, String> {
    let get = |k: &str| {
        query.split('&').find_map(|kv| kv.strip_prefix(k).and_then(|r| r.strip_prefix('='))).ok_or(format!("no {k}"))
    };
    let c2w: Vec<f64> = get("c2w")?
        .split(',')
        .map(|x| x.parse::<f64>().map_err(|_| format!("c2w: {x:?}")))
        .collect::<Result<_, _>>()?;
    if c2w.len() != 12 || c2w.iter().any(|x| !x.is_finite() || x.abs() > 1e6) {
        return Err("c2w must be 12 finite numbers (3 rows of 4)".into());
    }
    let side = |k: &str| -> Result<u32, String> {
        get(k)?.parse::<u32>().ok().filter(|v| (1..=max_side).contains(v)).ok_or(format!("{k} must be 1 to {max_side}"))
    };
    let fov =
        get("fov")?.parse::<f64>().ok().filter(|f| *f > 0.01 && *f < 3.1).ok_or("fov must be 0.01 to 3.1 radians")?;
    let req = FrameRequest {
        c2w: std::array::from_fn(|r| std::array::from_fn(|c| c2w[4 * r + c])),
        width: side("width")?,
        height: side("height")?,
        fov,
    };
    // The camera the renderer will make: one it would refuse is the request's fault (400).
    Camera::from_camera_angle_x(req.width, req.height, req.fov, req.c2w).map_err(|e| format!("invalid camera: {e}"))?;
    Ok(req)
}

/// Renders `req` on the render thread and waits for it, looking every [`CLIENT_CHECK`] whether
/// the client is still there (`client_gone`); if not, the frame is dropped at its next band.
fn render(
    tx: &mpsc::Sender<Job>,
    req: FrameRequest,
    kind: Kind,
    client_gone: &dyn Fn() -> bool,
) -> Result<Frame, String> {
    let (reply, answer) = mpsc::channel();
    let cancel = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let job = Job { req, kind, reply, cancel: std::sync::Arc::clone(&cancel) };
    tx.send(job).map_err(|_| "the renderer has stopped".to_string())?;
    loop {
        match answer.recv_timeout(CLIENT_CHECK) {
            Ok(result) => return result,
            Err(mpsc::RecvTimeoutError::Timeout) => {
                if client_gone() {
                    cancel.store(true, std::sync::atomic::Ordering::SeqCst);
                }
            }
            Err(mpsc::RecvTimeoutError::Disconnected) => return Err("the renderer has stopped".to_string()),
        }
    }
}

/// What every request's thread shares.
struct Shared {
    /// The run's info (`/api/info`).
    info: String,
    /// The run folder.
    run: PathBuf,
    /// Who may ask.
    policy: HostPolicy,
    /// Stills queued or rendering ([`MAX_QUEUED_STILLS`]).
    stills: std::sync::atomic::AtomicUsize,
}

/// One request: the page, the run's info and metrics, a frame, or a stream of frames.
fn handle(request: crate::http::Request, tx: &mpsc::Sender<Job>, shared: &Shared) {
    use std::sync::atomic::Ordering;
    let (info, run) = (shared.info.as_str(), shared.run.as_path());
    if let Some(why) = shared.policy.refusal(&request) {
        return request.respond(403, "text/plain", format!("forbidden: {why}").as_bytes());
    }
    let url = request.url().to_string();
    let (path, query) = url.split_once('?').unwrap_or((&url, ""));
    if request.method() != "GET" {
        return request.respond(405, "text/plain", b"only GET");
    }
    match path {
        "/" | "/index.html" => request.respond(200, "text/html; charset=utf-8", PAGE.as_bytes()),
        "/api/info" => request.respond(200, "application/json", info.as_bytes()),
        "/api/metrics" => request.respond(200, "application/json", metrics_json(run).as_bytes()),
        "/api/render" => match parse_frame(query, MAX_STILL_SIDE) {
            Err(e) => request.respond(400, "text/plain", e.as_bytes()),
            Ok(req) => {
                if shared.stills.fetch_add(1, Ordering::SeqCst) >= MAX_QUEUED_STILLS {
                    shared.stills.fetch_sub(1, Ordering::SeqCst);
                    let busy = format!("busy: {MAX_QUEUED_STILLS} frames are already waiting; ask again");
                    return request.respond(503, "text/plain", busy.as_bytes());
                }
                let answer = render(tx, req, Kind::Still, &|| request.client_gone());
                shared.stills.fetch_sub(1, Ordering::SeqCst);
                match answer {
                    Ok(f) => request.respond(200, "image/png", &f.png),
                    Err(e) if e == PREEMPTED => request.respond(503, "text/plain", e.as_bytes()),
                    Err(e) => request.respond(500, "text/plain", e.as_bytes()),
                }
            }
        },
        p if p.starts_with("/api/val/") => {
            // The latest validation render of one scale (`train --val-every`).
            match p["/api/val/".len()..].parse::<u32>().ok().filter(|j| *j < 16) {
                None => request.respond(404, "text/plain", format!("no such page: {path}").as_bytes()),
                Some(j) => match std::fs::read(RunDir::new(run).val().join(format!("scale{j}.png"))) {
                    Ok(png) => request.respond(200, "image/png", &png),
                    Err(_) => request.respond(404, "text/plain", b"no validation render yet (train --val-every)"),
                },
            }
        }
        "/api/stream" => match parse_frame(query, MAX_SIDE) {
            Err(e) => request.respond(400, "text/plain", e.as_bytes()),
            Ok(req) => stream(request, tx, req),
        },
        _ => request.respond(404, "text/plain", format!("no such page: {path}").as_bytes()),
    }
}

/// Server-sent events: the frame at 1/8, 1/4, 1/2 and full size, each as soon as it is rendered;
/// stops early when the page closes the stream (the camera moved).
fn stream(request: crate::http::Request, tx: &mpsc::Sender<Job>, req: FrameRequest) {
    let mut w = request.into_stream();
    let head =
        "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-cache\r\nConnection: close\r\n\r\n";
    if w.write_all(head.as_bytes()).and_then(|()| w.flush()).is_err() {
        return;
    }
    for level in (0..LEVELS).rev() {
        let scaled = |s: u32| (s >> level).max(8.min(s));
        let r = FrameRequest { width: scaled(req.width), height: scaled(req.height), ..req };
        let event = match render(tx, r, Kind::Stream, &|| crate::http::gone(&w)) {
            Ok(f) => serde_json::json!({
                "level": level, "width": f.width, "height": f.height, "ms": f.ms, "step": f.step,
                "png": base64::engine::general_purpose::STANDARD.encode(&f.png),
            })
            .to_string(),
            Err(e) => {
                let _ = write!(w, "event: failed\ndata: {}\n\n", serde_json::json!(e)).and_then(|()| w.flush());
                return;
            }
        };
        if write!(w, "data: {event}\n\n").and_then(|()| w.flush()).is_err() {
            return;
        }
    }
    let _ = write!(w, "event: done\ndata: {{}}\n\n").and_then(|()| w.flush());
}

#[cfg(test)]
mod tests {
    use super::*;
    use mipnerf_core::PixelCenters;
    use mipnerf_core::dataset::Ndc;

    /// Ray components of a band and of the whole image agree to this (f64 pixel offsets folded
    /// into `pix2cam` move the f32 rays by an ulp at most).
    const RAY_TOLERANCE: f32 = 1e-6;

    /// Every band's rays are the whole image's rays for its rows, for frames split into one or
    /// many bands (a short last band joined to the one before), with and without NDC and
    /// supersampling; the bands cover every row once.
    #[test]
    fn a_frame_rendered_in_bands_has_the_whole_frames_rays() {
        let pose = mipnerf_core::demo::camera_pose(0.3, 0.5);
        for (w, h, ndc, k) in
            [(24, 20, false, 1), (100, 83, false, 1), (64, 131, true, 1), (40, 205, false, 2), (3, 2, false, 1)]
        {
            let camera = Camera::from_camera_angle_x(w, h, 0.7, pose).unwrap();
            let ndc = ndc.then_some(Ndc { focal: 30.0, width: w as f32, height: h as f32 });
            let image = ImageSpec { camera, near: 2.0, far: 6.0, centers: PixelCenters::Centered, ndc, supersample: k };
            let mut whole = Vec::new();
            image.push_rays(0, image.pixels(), &mut whole);
            let bands = bands(w, h);
            assert_eq!(bands.first().map(|b| b.0), Some(0));
            assert_eq!(bands.last().map(|b| b.1), Some(h));
            assert!(bands.windows(2).all(|p| p[0].1 == p[1].0), "{bands:?}");
            assert!(h < 3 || bands.iter().all(|b| b.1 - b.0 >= 3), "{bands:?}");
            let mut banded = Vec::new();
            for (y0, y1) in bands {
                let (spec, extra) = band(&image, y0, y1);
                let mut rays = Vec::new();
                spec.push_rays(0, spec.pixels(), &mut rays);
                assert_eq!(rays.len(), (spec.pixels()) * k * k);
                rays.truncate(rays.len() - extra * k * k);
                banded.extend(rays);
            }
            assert_eq!(banded.len(), whole.len(), "{w}x{h}");
            let mut bad = Vec::new();
            for (i, (a, b)) in whole.iter().zip(&banded).enumerate() {
                let close = |x: glam::Vec3, y: glam::Vec3| {
                    (x - y).abs().max_element() <= RAY_TOLERANCE * (1.0 + x.abs().max_element())
                };
                if !(close(a.origin, b.origin) && close(a.direction, b.direction) && close(a.viewdir, b.viewdir))
                    || (a.radius - b.radius).abs() > RAY_TOLERANCE * a.radius
                {
                    bad.push(format!("ray {i}: {a:?} != {b:?}"));
                }
            }
            assert!(
                bad.is_empty(),
                "{w}x{h} ndc {ndc:?} k {k}: {} rays differ:\n{}",
                bad.len(),
                bad[..bad.len().min(5)].join("\n")
            );
        }
    }
}
