//! `nerf view`'s HTTP API, through a real server on a free loopback port: frames equal to
//! `nerf render --raw`, bad requests refused while the server keeps serving, and abandoned or
//! superseded frames dropped.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, TcpStream};
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

mod common;
use common::{max_byte_difference, nerf, nerf_ok, read_npy, stderr};

/// The most seconds a small frame may take after abandoned or abusive requests, or an idle
/// connection may stay open past a 0.4 s header timeout. The frames abandoned take minutes
/// (4096²); the bound leaves room for a loaded 2-core machine (3 s failed once beside the
/// rest of the suite).
const NEXT_FRAME_SECONDS: f64 = 10.0;

/// Starts `nerf view --port 0 ARGS…` with `stdout` and `stderr`.
fn spawn_view(args: &[&str], stdout: Stdio, stderr: Stdio) -> Child {
    common::nerf_command()
        .args(["view", "--port", "0"])
        .args(args)
        .stdout(stdout)
        .stderr(stderr)
        .spawn()
        .expect("start nerf view")
}

/// The first line read from `from` (the reader is dropped after it).
fn first_line(from: impl Read) -> String {
    let mut line = String::new();
    BufReader::new(from).read_line(&mut line).unwrap();
    line
}

/// The `host:port` of the `http://host:port/…` address in `line`, if any.
fn address_in(line: &str) -> Option<String> {
    line.split("http://")
        .nth(1)
        .and_then(|rest| rest.split('/').next())
        .map(str::to_string)
}

/// A running `nerf view`, killed when dropped.
struct Server {
    child: Child,
    addr: String,
}

impl Server {
    fn start(args: &[&str]) -> Server {
        let mut child = spawn_view(args, Stdio::piped(), Stdio::null());
        let line = first_line(child.stdout.take().unwrap());
        let addr = address_in(&line).unwrap_or_else(|| panic!("no address in {line:?}"));
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

    /// The error message of a render refused with status 400 for the query `query`, after
    /// checking that it names `reason`.
    fn refused_render(&self, query: &str, reason: &str) -> String {
        let (status, _, body) = self.get(&format!("/render.png?{query}"));
        let message = String::from_utf8_lossy(&body).to_string();
        assert_eq!(status, 400, "{query}: {message}");
        assert!(message.contains(reason), "{query}: {message}");
        message
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
    nerf_ok(&args);
    let (shape, expected) = read_npy(&dir.path().join("color_000.npy"));
    let mut args = vec!["--config", config];
    args.extend(overrides);
    let server = Server::start(&args);
    let (status, headers, body) = server.get(&format!("/render.png?{query}"));
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    assert_eq!(header(&headers, "content-type"), "image/png");
    let png = image::load_from_memory(&body).unwrap().to_rgb8();
    assert_eq!(vec![png.height() as u64, png.width() as u64, 3], shape);
    let worst = max_byte_difference(png.as_raw(), &expected);
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
        "/apps/nerf/src/view/viewer.html",
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
        server.refused_render(query, reason);
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
        "GET /render.png?width=2048&height=2048 HTTP/1.1\r\nHost: {}\r\n\r\n",
        server.addr
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
        write!(stream, "GET /render.png?width=2048&height=2048&client=page&gen=1 HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n").unwrap();
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

// The viewer under abuse: bounded counts, loopback only, a few seconds in all.

impl Server {
    /// Sends `bytes` as they are and returns all the reply (read until the server closes, at
    /// most 30 s).
    fn raw(&self, bytes: &str) -> String {
        let mut stream = TcpStream::connect(&self.addr).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(30)))
            .unwrap();
        stream.write_all(bytes.as_bytes()).unwrap();
        let mut reply = Vec::new();
        let _ = stream.read_to_end(&mut reply);
        String::from_utf8_lossy(&reply).to_string()
    }

    /// A request for `target`, written and left waiting for its reply.
    fn send(&self, target: &str) -> TcpStream {
        let mut stream = TcpStream::connect(&self.addr).unwrap();
        write!(
            stream,
            "GET {target} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            self.addr
        )
        .unwrap();
        stream
    }

    /// The server's resident memory in MB.
    fn resident_mb(&self) -> f64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).unwrap();
        let kb: f64 = status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            .unwrap();
        kb / 1024.0
    }
}

/// Seconds until the server closes `stream`, at most 20 s, and what it sent.
fn seconds_until_closed(mut stream: TcpStream) -> (f64, String) {
    let start = Instant::now();
    stream
        .set_read_timeout(Some(Duration::from_secs(20)))
        .unwrap();
    let mut reply = Vec::new();
    let mut buf = [0u8; 4096];
    while let Ok(n) = stream.read(&mut buf) {
        if n == 0 {
            break;
        }
        reply.extend_from_slice(&buf[..n]);
    }
    let reply = String::from_utf8_lossy(&reply).to_string();
    (start.elapsed().as_secs_f64(), reply)
}

/// Many 4096² requests whose clients hang up as soon as they are sent, then a small frame:
/// it must not wait for their rays (each would be 16.7M).
fn requests_abandoned_at_once_cost_nothing(server: &Server) {
    let before = server.stats();
    for i in 0..40 {
        // Half of them `Connection: close`, whose socket hyper stops reading.
        let mut stream = TcpStream::connect(&server.addr).unwrap();
        let close = ["", "Connection: close\r\n"][i % 2];
        write!(
            stream,
            "GET /render.png?width=4096&height=4096&client=gone{i} HTTP/1.1\r\nHost: {}\r\n{close}\r\n",
            server.addr
        )
        .unwrap();
        stream.shutdown(Shutdown::Both).unwrap();
    }
    let start = Instant::now();
    let (status, _, _) = server.get("/render.png?width=32&height=32");
    let seconds = start.elapsed().as_secs_f64();
    assert_eq!(status, 200);
    eprintln!("40 requests abandoned at once, then a 32² frame in {seconds:.2} s");
    assert!(
        seconds < NEXT_FRAME_SECONDS,
        "the next frame took {seconds:.2} s"
    );
    let stats = server.stats();
    assert_eq!(stats["waiting"], 0, "{stats}");
    assert_eq!(
        stats["rendered"].as_u64().unwrap() - before["rendered"].as_u64().unwrap(),
        1,
        "{stats}"
    );
}

/// More clients at once than the queue holds: the excess is answered 503 at once, with
/// Retry-After, and the server's memory stays that of one frame. Then they all hang up: the
/// rendering frame and the waiting ones are dropped, and the next frame comes at once.
fn a_flood_beyond_the_queue_is_refused_then_abandoned(server: &Server) {
    let info = {
        let (_, _, body) = server.get("/info.json");
        serde_json::from_slice::<serde_json::Value>(&body).unwrap()
    };
    let capacity = info["queue"].as_u64().unwrap() as usize;
    let n = capacity + 32;
    let before = server.stats();
    let count =
        |s: &serde_json::Value, key: &str| s[key].as_u64().unwrap() - before[key].as_u64().unwrap();
    // `Connection: close` each: hyper does not watch these sockets while a frame is made.
    let streams: Vec<TcpStream> = (0..n)
        .map(|i| {
            server.send(&format!(
                "/render.png?width=4096&height=4096&client=flood{i}"
            ))
        })
        .collect();
    // One renders, `capacity` wait, the rest are refused (one more when the render thread
    // had not yet taken the first when the queue filled).
    let start = Instant::now();
    let refused = loop {
        let stats = server.stats();
        let refused = count(&stats, "refused") as usize;
        let waiting = stats["waiting"].as_u64().unwrap() as usize;
        if refused + waiting + 1 >= n || start.elapsed() > Duration::from_secs(10) {
            assert_eq!(waiting, capacity, "{stats}");
            break refused;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(
        (n - capacity - 1..=n - capacity).contains(&refused),
        "{refused} of {n} refused"
    );
    let mut busy = 0;
    for stream in &streams {
        stream
            .set_read_timeout(Some(Duration::from_millis(50)))
            .unwrap();
        let mut reply = Vec::new();
        let _ = (&mut &*stream).read_to_end(&mut reply);
        let reply = String::from_utf8_lossy(&reply).to_ascii_lowercase();
        if reply.starts_with("http/1.1 503") {
            assert!(reply.contains("\r\nretry-after: 1\r\n"), "{reply}");
            assert!(reply.contains("busy"), "{reply}");
            busy += 1;
        }
    }
    assert_eq!(busy, refused);
    let resident = server.resident_mb();
    // Everyone hangs up.
    for stream in &streams {
        stream.shutdown(Shutdown::Both).unwrap();
    }
    drop(streams);
    let hung_up = Instant::now();
    let (status, _, _) = server.get("/render.png?width=32&height=32");
    let seconds = hung_up.elapsed().as_secs_f64();
    assert_eq!(status, 200);
    let stats = server.stats();
    eprintln!(
        "{n} clients at 4096²: {refused} refused at once, {resident:.0} MB resident; after they \
         hung up the next 32² frame came in {seconds:.2} s; {stats}"
    );
    assert!(resident < 1024.0, "{resident:.0} MB resident");
    assert!(
        seconds < NEXT_FRAME_SECONDS,
        "the next frame took {seconds:.2} s"
    );
    assert_eq!(count(&stats, "cancelled") as usize, n - refused, "{stats}");
    assert_eq!(count(&stats, "rendered"), 1, "{stats}");
    assert_eq!(stats["waiting"], 0, "{stats}");
}

/// Half a request head, or nothing, or an idle keep-alive connection: closed after the
/// header timeout (`--header-timeout-ms 400` below).
fn slow_and_idle_connections_are_closed(server: &Server) {
    let mut half = TcpStream::connect(&server.addr).unwrap();
    write!(half, "GET /info.json HTTP/1.1\r\nHost: 127.0").unwrap();
    let silent = TcpStream::connect(&server.addr).unwrap();
    let mut idle = TcpStream::connect(&server.addr).unwrap();
    write!(
        idle,
        "GET /info.json HTTP/1.1\r\nHost: {}\r\n\r\n",
        server.addr
    )
    .unwrap();
    let opened = Instant::now();
    for (what, stream) in [("half a head", half), ("nothing", silent), ("idle", idle)] {
        let (_, reply) = seconds_until_closed(stream);
        let seconds = opened.elapsed().as_secs_f64();
        eprintln!("{what}: closed after {seconds:.2} s");
        assert!(
            (0.3..NEXT_FRAME_SECONDS).contains(&seconds),
            "{what}: closed after {seconds:.2} s (timeout 0.4 s)"
        );
        if what == "idle" {
            assert!(reply.starts_with("HTTP/1.1 200"), "{reply}");
        } else {
            assert!(!reply.contains("200 OK"), "{reply}");
        }
    }
}

/// Requests whose Host is not this viewer's (DNS rebinding) are refused with a reason; the
/// loopback names are answered.
fn foreign_hosts_are_refused(server: &Server) {
    let port = server.addr.rsplit(':').next().unwrap();
    for host in [format!("evil.example:{port}"), "attacker.test".into()] {
        let reply = server.raw(&format!(
            "GET /render.png?width=4&height=4 HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"
        ));
        assert!(reply.starts_with("HTTP/1.1 403"), "{host}: {reply}");
        assert!(reply.contains("DNS rebinding"), "{reply}");
    }
    let reply = server.raw(&format!(
        "GET http://evil.example:{port}/info.json HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
        server.addr
    ));
    assert!(reply.starts_with("HTTP/1.1 403"), "{reply}");
    let reply = server.raw("GET /info.json HTTP/1.0\r\n\r\n");
    assert!(
        reply.starts_with("HTTP/1.0 400") || reply.starts_with("HTTP/1.1 400"),
        "{reply}"
    );
    assert!(reply.contains("Host header is required"), "{reply}");
    for host in [
        format!("localhost:{port}"),
        format!("[::1]:{port}"),
        "127.0.0.1".into(),
    ] {
        let reply = server.raw(&format!(
            "GET /info.json HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"
        ));
        assert!(reply.starts_with("HTTP/1.1 200"), "{host}: {reply}");
    }
}

/// Degenerate and non-finite cameras are 400s that name the bound.
fn degenerate_cameras_are_refused(server: &Server) {
    for (query, reason) in [
        ("focal=1e-300", "from 1e-3 to 1e3"),
        ("focal=1e300", "from 1e-3 to 1e3"),
        ("focal=-2", "focal"),
        ("focal=NaN", "focal"),
        ("eye=1e300,0,0", "at most 1e4"),
        ("eye=0,0,-inf", "eye"),
        ("up=0,nan,1", "up"),
        ("eye=0,0,-3&at=0,0,-3", "eye and at must differ"),
        // The box's default eye is (0, 0, −3), looking at the origin along +z.
        ("up=0,0,1", "parallel"),
        ("up=0,0,-7", "parallel"),
        ("width=0", "width"),
        ("height=4097", "height"),
    ] {
        let message = server.refused_render(query, reason);
        assert_eq!(message.trim_end().lines().count(), 1, "{message}");
    }
}

#[test]
fn the_viewer_holds_under_abuse() {
    let start = Instant::now();
    let server = Server::start(&[
        "--config",
        "box",
        "sampler.n_pts_per_ray=64",
        "--header-timeout-ms",
        "400",
    ]);
    let good = "/render.png?eye=0,0,-3&at=0,0,0&up=0,1,0&focal=1&width=24&height=16";
    let (status, _, first) = server.get(good);
    assert_eq!(status, 200);
    requests_abandoned_at_once_cost_nothing(&server);
    a_flood_beyond_the_queue_is_refused_then_abandoned(&server);
    slow_and_idle_connections_are_closed(&server);
    foreign_hosts_are_refused(&server);
    degenerate_cameras_are_refused(&server);
    // After all of that, the same frame, at once.
    let again = Instant::now();
    let (status, _, last) = server.get(good);
    assert_eq!(status, 200);
    assert_eq!(first, last, "the frame changed");
    assert!(again.elapsed().as_secs_f64() < NEXT_FRAME_SECONDS);
    eprintln!("abuse suite: {:.2} s", start.elapsed().as_secs_f64());
}

/// `nerf view` whose stdout cannot be written (a closed pipe, a full disk): the address goes
/// to stderr and the server serves.
#[test]
fn a_stdout_that_cannot_be_written_does_not_stop_the_server() {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    for (what, stdout) in [
        ("closed pipe", Stdio::from(writer)),
        ("full disk", Stdio::from(full)),
    ] {
        let args = ["--config", "box", "data.image_size=[8,8]"];
        let mut child = spawn_view(&args, stdout, Stdio::piped());
        let line = first_line(child.stderr.take().unwrap());
        assert!(line.contains("cannot write to stdout"), "{what}: {line}");
        let addr = address_in(&line).unwrap_or_else(|| panic!("{what}: no address in {line:?}"));
        let server = Server { child, addr };
        let (status, _, body) = server.get("/render.png");
        assert_eq!(status, 200, "{what}");
        assert_eq!(image::load_from_memory(&body).unwrap().width(), 8);
    }
}
