//! `nerf view`'s HTTP API, through a real server on a free loopback port: frames equal to
//! `nerf render --raw`, bad requests refused while the server keeps serving, and abandoned or
//! superseded frames dropped.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, TcpStream};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

mod common;
use common::{nerf, read_npy, stderr};

/// A running `nerf view`, killed when dropped.
struct Server {
    child: Child,
    addr: String,
}

impl Server {
    fn start(args: &[&str]) -> Server {
        let mut child = Command::new(env!("CARGO_BIN_EXE_nerf"))
            .args(["view", "--port", "0"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start nerf view");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let addr = line
            .split("http://")
            .nth(1)
            .and_then(|rest| rest.split('/').next())
            .unwrap_or_else(|| panic!("no address in {line:?}"))
            .to_string();
        Server { child, addr }
    }

    /// Sends a raw request line for `target`; returns status, headers (lower-case names) and
    /// body. Bounded by a 120 s timeout.
    fn request(&self, method: &str, target: &str) -> (u16, Vec<(String, String)>, Vec<u8>) {
        let mut stream = TcpStream::connect(&self.addr).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(120)))
            .unwrap();
        write!(
            stream,
            "{method} {target} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            self.addr
        )
        .unwrap();
        let mut bytes = Vec::new();
        stream.read_to_end(&mut bytes).unwrap();
        let split = bytes
            .windows(4)
            .position(|w| w == b"\r\n\r\n")
            .expect("no header end");
        let head = String::from_utf8_lossy(&bytes[..split]).to_string();
        let mut lines = head.lines();
        let status = lines
            .next()
            .unwrap()
            .split(' ')
            .nth(1)
            .unwrap()
            .parse()
            .unwrap();
        let headers = lines
            .filter_map(|l| l.split_once(':'))
            .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
            .collect();
        (status, headers, bytes[split + 4..].to_vec())
    }

    fn get(&self, target: &str) -> (u16, Vec<(String, String)>, Vec<u8>) {
        self.request("GET", target)
    }

    /// The counters of `/info.json`.
    fn stats(&self) -> serde_json::Value {
        let (status, _, body) = self.get("/info.json");
        assert_eq!(status, 200);
        serde_json::from_slice::<serde_json::Value>(&body).unwrap()["stats"].clone()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn header<'a>(headers: &'a [(String, String)], name: &str) -> &'a str {
    headers
        .iter()
        .find(|(k, _)| k == name)
        .map(|(_, v)| v.as_str())
        .unwrap_or_else(|| panic!("no {name}"))
}

/// `/render.png` for `query` against `nerf render --raw`'s frame 0 of the same config.
fn assert_frame_matches_raw(config: &str, overrides: &[&str], query: &str) -> (f64, f64) {
    let dir = tempfile::tempdir().unwrap();
    let mut args = vec![
        "render",
        "--config",
        config,
        "--raw",
        "--out-dir",
        dir.path().to_str().unwrap(),
        "cameras.n_poses=1",
    ];
    args.extend(overrides);
    let o = nerf(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let (shape, expected) = read_npy(&dir.path().join("color_000.npy"));
    let mut args = vec!["--config", config];
    args.extend(overrides);
    let server = Server::start(&args);
    let (status, headers, body) = server.get(&format!("/render.png?{query}"));
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    assert_eq!(header(&headers, "content-type"), "image/png");
    let png = image::load_from_memory(&body).unwrap().to_rgb8();
    assert_eq!(vec![png.height() as u64, png.width() as u64, 3], shape);
    let worst = png
        .as_raw()
        .iter()
        .zip(&expected)
        .map(|(b, v)| (*b as f32 / 255.0 - v).abs())
        .fold(0.0, f32::max);
    assert!(
        worst <= 1.0 / 255.0 + 1e-6,
        "{config}: /render.png differs from render --raw by {worst}"
    );
    let seconds: f64 = header(&headers, "x-frame-seconds").parse().unwrap();
    let fraction: f64 = header(&headers, "x-evaluated-fraction").parse().unwrap();
    assert!(seconds > 0.0 && (0.0..=1.0).contains(&fraction));
    (seconds, fraction)
}

#[test]
fn render_png_is_the_render_raw_frame() {
    // The box's surround camera 0: eye (0, 0, −3), at the origin, y up, focal 1; 48×40.
    let (_, fraction) = assert_frame_matches_raw(
        "box",
        &["sampler.n_pts_per_ray=32", "data.image_size=[48,40]"],
        "eye=0,0,-3&at=0,0,0&up=0,1,0&focal=1&width=48&height=40",
    );
    assert_eq!(fraction, 1.0, "an SDF is evaluated at every sample");
    // The shipped NeRF with its occupancy grid: surround camera 0 of the lego config is at
    // (0, 4, 2) with z up and focal 2. Rendered in bands, it still matches.
    let (_, fraction) = assert_frame_matches_raw(
        "lego",
        &["data.image_size=[80,80]"],
        "eye=0,4,2&at=0,0,0&up=0,0,1&focal=2&width=80&height=80",
    );
    assert!(
        fraction < 0.2,
        "the occupancy grid skips most samples: {fraction}"
    );
}

#[test]
fn bad_requests_are_refused_and_the_server_keeps_serving() {
    let server = Server::start(&[
        "--config",
        "box",
        "sampler.n_pts_per_ray=8",
        "data.image_size=[16,16]",
    ]);
    let (status, headers, body) = server.get("/");
    assert_eq!(status, 200);
    assert!(header(&headers, "content-type").starts_with("text/html"));
    assert!(String::from_utf8_lossy(&body).contains("<canvas"));
    for target in [
        "/nope",
        "/../etc/passwd",
        "/%2e%2e/%2e%2e/etc/passwd",
        "/..%2fCargo.toml",
        "//etc/passwd",
        "/src/app/viewer.html",
        "/render.png/../Cargo.toml",
    ] {
        let (status, _, _) = server.get(target);
        assert_eq!(status, 404, "{target}");
    }
    for (query, reason) in [
        ("width=4097", "width"),
        ("height=0", "height"),
        ("width=99999999999999999999", "width"),
        ("eye=nan,0,0", "eye"),
        ("eye=0,0,inf", "eye"),
        ("at=1,2", "at"),
        ("focal=inf", "focal"),
        ("focal=0", "focal"),
        ("eye=1,1,1&at=1,1,1", "eye and at must differ"),
        ("up=0,0,0", "up"),
        ("zoom=3", "unknown parameter"),
    ] {
        let (status, _, body) = server.get(&format!("/render.png?{query}"));
        let message = String::from_utf8_lossy(&body);
        assert_eq!(status, 400, "{query}: {message}");
        assert!(message.contains(reason), "{query}: {message}");
    }
    assert_eq!(server.request("POST", "/render.png").0, 405);
    // Still serving.
    let (status, _, body) = server.get("/render.png?width=8&height=8");
    assert_eq!(status, 200);
    assert_eq!(image::load_from_memory(&body).unwrap().width(), 8);
    assert_eq!(server.stats()["rendered"], 1);
}

/// Polls `/info.json` (every 50 ms, at most `limit`) until `counter` reaches `at_least`.
fn wait_for(server: &Server, counter: &str, at_least: u64, limit: Duration) -> u64 {
    let start = Instant::now();
    loop {
        let n = server.stats()[counter].as_u64().unwrap();
        if n >= at_least || start.elapsed() > limit {
            return n;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_client_that_hangs_up_stops_its_frame() {
    // 2048² at 64 samples: seconds of work, in 512 bands of 8192 rays.
    let server = Server::start(&["--config", "box", "sampler.n_pts_per_ray=64"]);
    let mut stream = TcpStream::connect(&server.addr).unwrap();
    write!(
        stream,
        "GET /render.png?width=2048&height=2048 HTTP/1.1\r\nHost: x\r\n\r\n"
    )
    .unwrap();
    std::thread::sleep(Duration::from_millis(300));
    stream.shutdown(Shutdown::Both).unwrap();
    drop(stream);
    let hung_up = Instant::now();
    assert_eq!(
        wait_for(&server, "cancelled", 1, Duration::from_secs(60)),
        1,
        "the frame was not cancelled"
    );
    // The next request is served at once, not after the abandoned frame.
    let (status, _, _) = server.get("/render.png?width=32&height=32");
    assert_eq!(status, 200);
    eprintln!(
        "hung up, cancelled and served the next frame in {:.2} s",
        hung_up.elapsed().as_secs_f64()
    );
    assert_eq!(server.stats()["rendered"], 1);
}

#[test]
fn a_newer_request_from_the_same_page_supersedes_the_stale_one() {
    let server = Server::start(&["--config", "box", "sampler.n_pts_per_ray=64"]);
    let addr = server.addr.clone();
    let stale = std::thread::spawn(move || {
        let mut stream = TcpStream::connect(&addr).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(120)))
            .unwrap();
        write!(stream, "GET /render.png?width=2048&height=2048&client=page&gen=1 HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").unwrap();
        let mut reply = String::new();
        let _ = stream.read_to_string(&mut reply);
        reply
    });
    std::thread::sleep(Duration::from_millis(300));
    let (status, _, _) = server.get("/render.png?width=32&height=32&client=page&gen=2");
    assert_eq!(status, 200);
    let reply = stale.join().unwrap();
    assert!(
        reply.starts_with("HTTP/1.1 409"),
        "{}",
        reply.lines().next().unwrap_or("")
    );
    let stats = server.stats();
    assert_eq!(
        (stats["superseded"].as_u64(), stats["rendered"].as_u64()),
        (Some(1), Some(1))
    );
}

#[test]
fn a_port_in_use_is_a_one_line_error() {
    let server = Server::start(&["--config", "box"]);
    let port = server.addr.rsplit(':').next().unwrap();
    let o = nerf(&["view", "--config", "box", "--port", port]);
    let err = stderr(&o);
    assert!(!o.status.success());
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains(&format!("cannot listen on 127.0.0.1:{port}")),
        "{err}"
    );
    // The running server is unaffected.
    assert_eq!(server.get("/render.png?width=4&height=4").0, 200);
}
