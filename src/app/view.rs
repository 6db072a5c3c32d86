//! `nerf view`: a web page that shows a scene live, and the HTTP API it uses.
//!
//! * `GET /` — the page (`viewer.html`, built into the binary: no network needed).
//! * `GET /render.png?eye=x,y,z&at=x,y,z&up=x,y,z&focal=F&width=W&height=H[&client=ID&gen=N]`
//!   — one view as PNG (pytorch3d `look_at_view_transform`, NDC focal, as the surround
//!   cameras); headers `X-Frame-Seconds`, `X-Evaluated-Fraction`, `X-Samples-Total`,
//!   `X-Samples-Evaluated`. Left-out parameters take the config's first surround camera and
//!   image size. A bad query is a 400 with the reason; a request overtaken by a newer one of
//!   the same `client` is a 409.
//! * `GET /info.json` — the scene, the default camera, the limits and counters.
//! * anything else — 404. Nothing is read from disk, so no path can reach a file.
//!
//! Rendering runs on one worker thread, one frame at a time. Before each band of rays it asks
//! whether the frame is still wanted: not when the same page has sent a newer request (its
//! generation counter moved on), nor when the client hung up (hyper then drops the request's
//! handler, whose guard raises the frame's cancel flag). Stale work therefore ends within one
//! band and never holds up the frame the page is waiting for.

use std::collections::HashMap;
use std::net::{SocketAddr, TcpListener, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{Context, Result};
use axum::extract::{Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use candle_core::Device;
use glam::DVec3;

use crate::app::config::{limits, Config};
use crate::app::scene::SceneField;
use crate::app::view_request::{parse_view_query, ViewDefaults, ViewRequest};
use crate::io::images::png_bytes;
use crate::render::renderer::VolumeRenderer;
use crate::render::sampler::StratifiedSampler;
use crate::render::view::render_view_interruptible;

/// The page, built into the binary.
const PAGE: &str = include_str!("viewer.html");

/// Most pages whose newest generation is remembered.
const MAX_CLIENTS: usize = 1024;

/// Rays rendered between two checks whether a frame is still wanted (the NeRF renderer's own
/// chunk: 2^15 samples at 4 per ray).
const BAND: usize = 8192;

/// Counters shown in `/info.json`.
#[derive(Debug, Default)]
struct Stats {
    rendered: AtomicU64,
    superseded: AtomicU64,
    cancelled: AtomicU64,
    failed: AtomicU64,
}

/// What the handlers and the render worker share.
#[derive(Debug, Default)]
struct Clients {
    /// The newest generation each page has asked for.
    latest: Mutex<HashMap<String, u64>>,
    stats: Stats,
}

impl Clients {
    /// Records a request's generation; a lower one than already seen changes nothing.
    fn register(&self, request: &ViewRequest) {
        if let Some(c) = &request.client {
            let mut latest = self.latest.lock().unwrap_or_else(|e| e.into_inner());
            // Bounded: a script inventing client ids cannot grow the map without end (the
            // pages forgotten here merely lose the dropping of their stale frames).
            if latest.len() >= MAX_CLIENTS && !latest.contains_key(c) {
                latest.clear();
            }
            let g = latest.entry(c.clone()).or_insert(request.generation);
            *g = (*g).max(request.generation);
        }
    }

    /// Whether a newer request of the same page has arrived.
    fn is_stale(&self, request: &ViewRequest) -> bool {
        let Some(c) = &request.client else {
            return false;
        };
        let latest = self.latest.lock().unwrap_or_else(|e| e.into_inner());
        latest.get(c).is_some_and(|&g| g > request.generation)
    }
}

/// A rendered frame, ready to send.
struct Frame {
    png: Vec<u8>,
    seconds: f64,
    total: usize,
    evaluated: usize,
}

/// How a job ended.
enum Outcome {
    Done(Frame),
    Superseded,
    Cancelled,
    Failed(String),
}

/// One frame to render, and where to send it.
struct Job {
    request: ViewRequest,
    cancel: Arc<AtomicBool>,
    reply: tokio::sync::oneshot::Sender<Outcome>,
}

/// Raises a job's cancel flag when the request's handler is dropped (the reply was sent, or the
/// client hung up and hyper abandoned the request).
struct CancelOnDrop(Arc<AtomicBool>);

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// The render worker's fixed parts.
struct Worker {
    scene: SceneField,
    sampler: StratifiedSampler,
    renderer: VolumeRenderer,
    device: Device,
    clients: Arc<Clients>,
}

impl Worker {
    /// Renders one job unless it is no longer wanted.
    fn run(&self, job: &Job) -> Outcome {
        let wanted = || !job.cancel.load(Ordering::Relaxed) && !self.clients.is_stale(&job.request);
        let r = &job.request;
        let start = Instant::now();
        let view = render_view_interruptible(
            self.scene.as_field(),
            &r.camera,
            (r.width, r.height),
            &self.sampler,
            &self.renderer,
            &self.device,
            BAND,
            &|| !wanted(),
        );
        match view {
            Ok(Some(view)) => match png_bytes(&view.color) {
                Ok(png) => Outcome::Done(Frame {
                    png,
                    seconds: start.elapsed().as_secs_f64(),
                    total: view.samples.total,
                    evaluated: view.samples.evaluated,
                }),
                Err(e) => Outcome::Failed(format!("{e:#}")),
            },
            Ok(None) if job.cancel.load(Ordering::Relaxed) => Outcome::Cancelled,
            Ok(None) => Outcome::Superseded,
            Err(e) => Outcome::Failed(format!("{e:#}")),
        }
    }

    /// Serves jobs until every sender is gone.
    fn serve(self, jobs: mpsc::Receiver<Job>) {
        for job in jobs {
            let outcome = self.run(&job);
            let counter = match &outcome {
                Outcome::Done(_) => &self.clients.stats.rendered,
                Outcome::Superseded => &self.clients.stats.superseded,
                Outcome::Cancelled => &self.clients.stats.cancelled,
                Outcome::Failed(_) => &self.clients.stats.failed,
            };
            counter.fetch_add(1, Ordering::Relaxed);
            // The handler may be gone (client hung up): nothing to send to.
            let _ = job.reply.send(outcome);
        }
    }
}

/// The handlers' state.
struct AppState {
    jobs: Mutex<mpsc::Sender<Job>>,
    clients: Arc<Clients>,
    defaults: ViewDefaults,
    info: serde_json::Value,
}

fn text(status: StatusCode, message: impl Into<String>) -> Response {
    let mut body = message.into();
    body.push('\n');
    (
        status,
        [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
        body,
    )
        .into_response()
}

async fn page() -> Response {
    ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], PAGE).into_response()
}

async fn not_found() -> Response {
    text(
        StatusCode::NOT_FOUND,
        "not found (the viewer serves /, /render.png and /info.json)",
    )
}

async fn info_json(State(state): State<Arc<AppState>>) -> Response {
    let s = &state.clients.stats;
    let mut info = state.info.clone();
    info["stats"] = serde_json::json!({
        "rendered": s.rendered.load(Ordering::Relaxed),
        "superseded": s.superseded.load(Ordering::Relaxed),
        "cancelled": s.cancelled.load(Ordering::Relaxed),
        "failed": s.failed.load(Ordering::Relaxed),
    });
    (
        [
            (header::CONTENT_TYPE, "application/json"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        info.to_string(),
    )
        .into_response()
}

async fn render(
    State(state): State<Arc<AppState>>,
    Query(pairs): Query<Vec<(String, String)>>,
) -> Response {
    let request = match parse_view_query(&pairs, &state.defaults) {
        Ok(r) => r,
        Err(message) => return text(StatusCode::BAD_REQUEST, message),
    };
    state.clients.register(&request);
    let cancel = Arc::new(AtomicBool::new(false));
    let _guard = CancelOnDrop(cancel.clone());
    let (reply, outcome) = tokio::sync::oneshot::channel();
    let job = Job {
        request,
        cancel,
        reply,
    };
    let sent = state
        .jobs
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .send(job);
    if sent.is_err() {
        return text(
            StatusCode::INTERNAL_SERVER_ERROR,
            "the render worker has stopped",
        );
    }
    match outcome.await {
        Ok(Outcome::Done(frame)) => frame_response(frame),
        Ok(Outcome::Superseded) => text(
            StatusCode::CONFLICT,
            "superseded by a newer request from the same client",
        ),
        Ok(Outcome::Cancelled) => text(StatusCode::SERVICE_UNAVAILABLE, "cancelled"),
        Ok(Outcome::Failed(e)) => text(StatusCode::INTERNAL_SERVER_ERROR, e),
        Err(_) => text(
            StatusCode::INTERNAL_SERVER_ERROR,
            "the render worker has stopped",
        ),
    }
}

fn frame_response(frame: Frame) -> Response {
    let fraction = frame.evaluated as f64 / frame.total.max(1) as f64;
    (
        [
            (header::CONTENT_TYPE, "image/png".to_string()),
            (header::CACHE_CONTROL, "no-store".to_string()),
            (
                header::HeaderName::from_static("x-frame-seconds"),
                format!("{:.4}", frame.seconds),
            ),
            (
                header::HeaderName::from_static("x-evaluated-fraction"),
                format!("{fraction:.5}"),
            ),
            (
                header::HeaderName::from_static("x-samples-total"),
                frame.total.to_string(),
            ),
            (
                header::HeaderName::from_static("x-samples-evaluated"),
                frame.evaluated.to_string(),
            ),
        ],
        frame.png,
    )
        .into_response()
}

/// Where `nerf view` listens.
#[derive(Debug, Clone)]
pub struct ViewOptions {
    /// Host name or address to bind (default 127.0.0.1: this machine only).
    pub host: String,
    /// Port (0 picks a free one; the address is printed).
    pub port: u16,
}

/// The config's first surround camera and image size, the view a bare `/render.png` gets.
fn view_defaults(config: &Config) -> ViewDefaults {
    let c = &config.cameras;
    let eye = config
        .surround_cameras()
        .first()
        .map_or(DVec3::new(0.0, 0.0, c.radius), |cam| cam.center());
    let (width, height) = config.image_size();
    ViewDefaults {
        eye,
        at: DVec3::ZERO,
        up: DVec3::from_array(c.up),
        focal: c.focal_length,
        width,
        height,
    }
}

/// Binds the listener, with an error that names the address.
fn bind(options: &ViewOptions) -> Result<TcpListener> {
    let target = format!("{}:{}", options.host, options.port);
    let addrs: Vec<SocketAddr> = (options.host.as_str(), options.port)
        .to_socket_addrs()
        .with_context(|| format!("--host {}: not an address", options.host))?
        .collect();
    let listener =
        TcpListener::bind(&addrs[..]).with_context(|| format!("cannot listen on {target}"))?;
    listener.set_nonblocking(true)?;
    Ok(listener)
}

/// `nerf view`: serves the page and the API for `scene` (named `name`) until killed. Prints
/// `nerf view: <name> at http://<address>/` once listening.
pub fn serve(
    config: &Config,
    name: &str,
    scene: SceneField,
    options: &ViewOptions,
    device: &Device,
) -> Result<()> {
    let listener = bind(options)?;
    let addr = listener.local_addr()?;
    let defaults = view_defaults(config);
    let clients = Arc::new(Clients::default());
    let worker = Worker {
        scene,
        sampler: config.sampler()?,
        renderer: config.renderer()?,
        device: device.clone(),
        clients: clients.clone(),
    };
    let kind = match worker.scene {
        SceneField::Sdf { .. } => "sdf",
        SceneField::Nerf(_) => match config.implicit_function {
            crate::app::config::ImplicitFunctionConfig::Ngp(_) => "ngp",
            _ => "nerf",
        },
    };
    let info = serde_json::json!({
        "scene": name, "field": kind,
        "eye": defaults.eye.to_array(), "at": defaults.at.to_array(), "up": defaults.up.to_array(),
        "focal": defaults.focal, "width": defaults.width, "height": defaults.height,
        "max_side": limits::IMAGE_SIDE,
    });
    let (jobs, queue) = mpsc::channel();
    std::thread::Builder::new()
        .name("render".into())
        .spawn(move || worker.serve(queue))?;
    let state = Arc::new(AppState {
        jobs: Mutex::new(jobs),
        clients,
        defaults,
        info,
    });
    let app = Router::new()
        .route("/", get(page))
        .route("/index.html", get(page))
        .route("/render.png", get(render))
        .route("/info.json", get(info_json))
        .fallback(not_found)
        .with_state(state);
    if !addr.ip().is_loopback() {
        eprintln!("warning: listening on {addr}: anyone who can reach it can use the viewer");
    }
    println!("nerf view: {name} at http://{addr}/ (Ctrl-C to stop)");
    use std::io::Write;
    std::io::stdout().flush()?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::from_std(listener)?;
        axum::serve(listener, app).await
    })?;
    Ok(())
}
