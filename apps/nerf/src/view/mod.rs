//! `nerf view`: a web page that shows a scene live, and the HTTP API it uses.
//!
//! * `GET /` — the page (`viewer.html`, built into the binary: no network needed).
//! * `GET /render.png?eye=x,y,z&at=x,y,z&up=x,y,z&focal=F&width=W&height=H[&client=ID&gen=N]`
//!   — one view as PNG (pytorch3d `look_at_view_transform`, NDC focal, as the surround
//!   cameras); headers `X-Frame-Seconds`, `X-Evaluated-Fraction`, `X-Samples-Total`,
//!   `X-Samples-Evaluated`. Left-out parameters take the config's first surround camera and
//!   image size. A bad query, degenerate camera included, is a 400 naming the bound it broke
//!   (`view_request`); a request overtaken by a newer one of the same `client` is a 409; one
//!   that finds the queue full is a 503 with `Retry-After: 1` (`view_queue`).
//! * `GET /info.json` — the scene, the default camera, the limits and counters.
//! * anything else — 404. Nothing is read from disk, so no path can reach a file.
//!
//! Every request must name the viewer in its `Host` (`view_host`: loopback names when bound to
//! loopback), else 403, so that a page elsewhere cannot read frames through DNS rebinding.
//! A connection that has not sent a full request head within the header timeout (10 s; counted
//! from its opening or its previous response, so idle keep-alive connections close too) is
//! closed.
//!
//! Rendering runs on one worker thread, one frame at a time, fed by a bounded queue. Before
//! each band of rays, the first included, it asks whether the frame is still wanted: not when
//! the same page has sent a newer request (its generation counter moved on), nor when the
//! client hung up (hyper then drops the request's handler, whose guard raises the frame's
//! cancel flag). Stale work therefore ends within one band and never holds up the frame the
//! page is waiting for. Nothing on this path panics on a stdout or stderr that cannot be
//! written.

pub mod host;
pub mod queue;
pub mod request;

use std::io::Write;
use std::net::{SocketAddr, TcpListener, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use axum::extract::{Query, Request, State};
use axum::http::{header, StatusCode};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Extension, Router};
use candle_core::Device;
use glam::DVec3;
use hyper::body::Incoming;
use hyper::server::conn::http1;
use hyper::service::{service_fn, Service};
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;

use crate::render::scene::SceneField;
use crate::render::scene_frame::DefaultViews;
use crate::view::host::{AllowedHosts, HostRefusal};
use crate::view::queue::{Frame, Job, Outcome, Peer, Queue, QUEUE_CAPACITY};
use crate::view::request::{parse_view_query, ViewDefaults};
use nerf::config::{limits, Config};
use nerf::core::term::note;
use nerf::io::images::png_bytes;
use nerf::render::view::{render_view_interruptible, Interrupt, RenderSettings};

/// The page, built into the binary.
const PAGE: &str = include_str!("viewer.html");

/// Rays rendered between two checks whether a frame is still wanted.
const BAND: usize = 8192;

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
    render: RenderSettings,
    device: Device,
    queue: Arc<Queue>,
}

impl Worker {
    /// Renders one job unless it is no longer wanted (asked before each band, the first
    /// included).
    fn run(&self, job: &Job) -> Outcome {
        let r = &job.request;
        let start = Instant::now();
        let interrupt = Interrupt {
            band: BAND,
            stop: &|| self.queue.unwanted(job),
        };
        let view = render_view_interruptible(
            &self.render.with(self.scene.as_field()),
            &nerf::Camera::from(r.camera),
            (r.width, r.height),
            &self.device,
            interrupt,
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
            Ok(None) if job.cancelled() => Outcome::Cancelled,
            Ok(None) => Outcome::Superseded,
            Err(e) => Outcome::Failed(format!("{e:#}")),
        }
    }

    /// Serves jobs for as long as the process runs.
    fn serve(self) {
        loop {
            let job = self.queue.pop();
            let outcome = self.run(&job);
            self.queue.answer(job, outcome);
        }
    }
}

/// The handlers' state.
struct AppState {
    queue: Arc<Queue>,
    defaults: ViewDefaults,
    info: serde_json::Value,
    hosts: AllowedHosts,
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

/// Answers only requests whose `Host` (and absolute-form target, if any) names this viewer.
async fn check_host(State(state): State<Arc<AppState>>, request: Request, next: Next) -> Response {
    let host = request.headers().get(header::HOST).map(|v| v.as_bytes());
    let target = request.uri().authority().map(|a| a.as_str().as_bytes());
    let checked = state
        .hosts
        .check(host)
        .and_then(|()| target.map_or(Ok(()), |t| state.hosts.check(Some(t))));
    match checked {
        Ok(()) => next.run(request).await,
        Err(HostRefusal::Missing) => text(
            StatusCode::BAD_REQUEST,
            "a Host header is required (HTTP/1.1)",
        ),
        Err(HostRefusal::Foreign(reason)) => text(StatusCode::FORBIDDEN, reason),
    }
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
    let s = &state.queue.stats;
    let mut info = state.info.clone();
    info["stats"] = serde_json::json!({
        "rendered": s.rendered.load(Ordering::Relaxed),
        "superseded": s.superseded.load(Ordering::Relaxed),
        "cancelled": s.cancelled.load(Ordering::Relaxed),
        "failed": s.failed.load(Ordering::Relaxed),
        "refused": s.refused.load(Ordering::Relaxed),
        "waiting": state.queue.waiting(),
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
    peer: Option<Extension<Peer>>,
    Query(pairs): Query<Vec<(String, String)>>,
) -> Response {
    let request = match parse_view_query(&pairs, &state.defaults) {
        Ok(r) => r,
        Err(message) => return text(StatusCode::BAD_REQUEST, message),
    };
    let cancel = Arc::new(AtomicBool::new(false));
    let _guard = CancelOnDrop(cancel.clone());
    let (reply, outcome) = tokio::sync::oneshot::channel();
    let job = Job {
        request,
        cancel,
        peer: peer.map(|Extension(p)| p),
        reply,
    };
    if state.queue.push(job).is_err() {
        let mut response = text(
            StatusCode::SERVICE_UNAVAILABLE,
            format!("busy: {QUEUE_CAPACITY} frames are already waiting; retry in a second"),
        );
        response
            .headers_mut()
            .insert(header::RETRY_AFTER, header::HeaderValue::from_static("1"));
        return response;
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
    /// How long a connection may take to send a request's head, counted from its opening or
    /// from its previous response (so also how long an idle keep-alive connection stays open;
    /// `nerf view` uses 10 s).
    pub header_timeout: Duration,
}

/// The first of the `views` (the config's surround cameras, or a capture's orbit or spiral:
/// [`crate::render::scene_frame::render_cameras`]) and the config's image size, the view a bare
/// `/render.png` gets. A capture's orbit looks at the origin with +z up, its spiral at its
/// focus point with the cameras' mean up.
fn view_defaults(config: &Config, views: &DefaultViews) -> ViewDefaults {
    let c = &config.cameras;
    let first = views.cameras.first();
    let eye = first.map_or(DVec3::new(0.0, 0.0, c.radius), |cam| cam.center());
    let (width, height) = config.image_size();
    ViewDefaults {
        eye,
        at: views.path.map_or(DVec3::ZERO, |p| p.target()),
        up: views.path.map_or(DVec3::from_array(c.up), |p| p.up()),
        focal: match (views.path, first) {
            (Some(_), Some(cam)) => cam.focal[0],
            _ => c.focal_length,
        },
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

/// Prints the address line on stdout. A stdout that cannot be written (a closed pipe, a full
/// disk) does not stop a server that is otherwise fine: the address goes to stderr instead.
fn announce(name: &str, addr: SocketAddr) {
    let url = format!("http://{addr}/");
    let mut out = std::io::stdout().lock();
    let printed =
        writeln!(out, "nerf view: {name} at {url} (Ctrl-C to stop)").and_then(|()| out.flush());
    if let Err(e) = printed {
        note(&format!(
            "warning: cannot write to stdout ({e}); nerf view: {name} at {url} (Ctrl-C to stop)"
        ));
    }
}

/// Accepts connections for ever, each served by hyper's HTTP/1.1 connection with a header
/// (and idle) timeout. A failed accept (too many open files) is reported and retried after a
/// pause rather than ending the server.
async fn accept_loop(listener: tokio::net::TcpListener, app: Router, header_timeout: Duration) {
    loop {
        let stream = match listener.accept().await {
            Ok((stream, _)) => stream,
            Err(e) => {
                note(&format!("warning: cannot accept a connection: {e}"));
                tokio::time::sleep(Duration::from_secs(1)).await;
                continue;
            }
        };
        let _ = stream.set_nodelay(true);
        // A second handle on the socket for the jobs to watch (see `Peer`).
        let Ok((stream, peer)) = stream.into_std().and_then(|s| {
            let peer = Peer::new(s.try_clone()?);
            Ok((tokio::net::TcpStream::from_std(s)?, peer))
        }) else {
            continue;
        };
        let router = TowerToHyperService::new(app.clone());
        let service = service_fn(move |mut request: hyper::Request<Incoming>| {
            request.extensions_mut().insert(peer.clone());
            router.call(request)
        });
        tokio::spawn(async move {
            let mut builder = http1::Builder::new();
            builder
                .timer(TokioTimer::new())
                .header_read_timeout(header_timeout);
            // A client that times out, hangs up or sends garbage ends its connection only.
            let _ = builder
                .serve_connection(TokioIo::new(stream), service)
                .await;
        });
    }
}

/// `nerf view`: serves the page and the API for `scene` (named `name`) until killed, the
/// first of `views` its default view. Prints
/// `nerf view: <name> at http://<address>/` once listening.
pub fn serve(
    config: &Config,
    name: &str,
    scene: SceneField,
    views: &DefaultViews,
    options: &ViewOptions,
    device: &Device,
) -> Result<()> {
    let listener = bind(options)?;
    let addr = listener.local_addr()?;
    let defaults = view_defaults(config, views);
    let queue = Arc::new(Queue::default());
    let worker = Worker {
        scene,
        render: config.render_settings()?,
        device: device.clone(),
        queue: queue.clone(),
    };
    let kind = match worker.scene {
        SceneField::Sdf { .. } => "sdf",
        SceneField::Nerf(_) => config.implicit_function.kind(),
    };
    let info = serde_json::json!({
        "scene": name, "field": kind,
        "eye": defaults.eye.to_array(), "at": defaults.at.to_array(), "up": defaults.up.to_array(),
        "focal": defaults.focal, "width": defaults.width, "height": defaults.height,
        "max_side": limits::IMAGE_SIDE, "queue": QUEUE_CAPACITY,
    });
    std::thread::Builder::new()
        .name("render".into())
        // On a pool of its own: the command's pool has a worker blocked in the HTTP server.
        .spawn(move || crate::worker_pool::on_own_pool(|| worker.serve()))?;
    let state = Arc::new(AppState {
        queue,
        defaults,
        info,
        hosts: AllowedHosts::new(&options.host, addr.ip()),
    });
    let app = Router::new()
        .route("/", get(page))
        .route("/index.html", get(page))
        .route("/render.png", get(render))
        .route("/info.json", get(info_json))
        .fallback(not_found)
        .layer(middleware::from_fn_with_state(state.clone(), check_host))
        .with_state(state);
    if !addr.ip().is_loopback() {
        note(&format!(
            "warning: listening on {addr}: anyone who can reach it can use the viewer"
        ));
    }
    announce(name, addr);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::from_std(listener)?;
        accept_loop(listener, app, options.header_timeout).await;
        anyhow::Ok(())
    })?;
    Ok(())
}
