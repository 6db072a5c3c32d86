//! `nerf view` in a real browser, used as a person would: headless Chromium, driven over the
//! DevTools protocol, loads the viewer on the lego scene, waits for its first full frame, orbits
//! with a mouse drag and zooms with the wheel (the picture must change each time), records a
//! two-keyframe camera path at 64 × 64, downloads it, and renders it with
//! `nerf render --camera-path` (exactly 4 frames and a GIF).
//!
//! Chromium: `$CHROMIUM`, else `/usr/bin/chromium` (Debian's package, which `.ci/install`
//! installs). Without it or the lego data the test prints SKIPPED and passes, and fails under
//! `CI=true`. The whole run is bounded by 240 s: every wait stops at that deadline, and a
//! watchdog kills the server and the browser when it passes (and ends the test binary should
//! the test still not have failed 10 s later). `NERF_BROWSER_SCREENSHOT=PATH`
//! saves a screenshot of the final view.
//!
//! The page is only touched through `window.viewer`'s fields and the element ids #view,
//! #status, #error, #res, #addKey, #perTransition and #download.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use headless_chrome::protocol::cdp::types::Event;
use headless_chrome::protocol::cdp::{Browser as Cdp, Emulation, Input, Page, Runtime};
use headless_chrome::{Browser, LaunchOptions, Tab};
use serde_json::Value;

mod common;

/// The bound on the whole run.
const RUN_LIMIT: Duration = Duration::from_secs(240);
/// How long the watchdog lets the test fail on its own after killing its processes.
const GRACE: Duration = Duration::from_secs(10);
/// The bound on the browser's own waits (loading the page, finding a button).
const PAGE_LIMIT: Duration = Duration::from_secs(30);
/// The bound on one frame (the first lego frame at 256² takes a few seconds here).
const FRAME_LIMIT: Duration = Duration::from_secs(120);
/// The page's size in CSS pixels.
const VIEWPORT: (u32, u32) = (960, 620);
/// Chromium's flags beyond the ones `headless_chrome` adds for `headless: true`,
/// `sandbox: false` and `enable_gpu: false` (--headless, --no-sandbox, --disable-gpu): no
/// network traffic of its own (QUIC, updates, sync), no first-run dialogs.
const CHROMIUM_FLAGS: [&str; 5] = [
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
];

#[test]
fn viewer_in_headless_chromium() -> Result<()> {
    let Some(chromium) = common::chromium() else {
        return Ok(());
    };
    if common::lego_dir().is_none() {
        return Ok(());
    }
    let started = Instant::now();
    let deadline = started + RUN_LIMIT;
    let scratch = tempfile::tempdir()?;
    // Declared in this order so that they drop in the reverse one: the watchdog stands down
    // first, then the browser and the server are stopped on every exit path.
    let server = Server::start(deadline)?;
    let browser = launch(&chromium, &scratch.path().join("profile"))?;
    let mut pids = vec![server.child.id()];
    pids.extend(browser.get_process_id());
    let _watchdog = Watchdog::start(deadline, pids, scratch.path().to_path_buf());

    let page = Viewer::open(&browser, &server.url, deadline)?;
    drive(&page, scratch.path(), deadline)?;
    println!(
        "browser test passed in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The scenario, on an open page whose first frame has not been waited for yet.
fn drive(page: &Viewer, scratch: &Path, deadline: Instant) -> Result<()> {
    page.settled(0)?;
    let status = page.text("status")?;
    ensure!(
        number_between(&status, "frame time ", " s").is_some()
            && number_between(&status, "samples evaluated ", " %").is_some(),
        "the status shows {status:?}"
    );
    println!("first frame: {}", status.replace('\n', "; "));

    // Drag to orbit: the picture must change.
    let change = page.change_by(|page| {
        let (cx, cy) = page.canvas_centre()?;
        let path: Vec<(f64, f64)> = (1..=8)
            .map(|i| (cx + 15.0 * i as f64, cy + 4.0 * i as f64))
            .collect();
        page.drag((cx, cy), &path)
    })?;
    println!("after the drag: mean pixel change {change:.2} / 255");
    ensure!(
        change > 2.0,
        "dragging did not change the view ({change:.2})"
    );

    // Wheel to zoom in: the picture changes again.
    let change = page.change_by(|page| page.wheel(page.canvas_centre()?, -400.0))?;
    println!("after the wheel: mean pixel change {change:.2} / 255");
    ensure!(
        change > 2.0,
        "the wheel did not change the view ({change:.2})"
    );

    // Two keyframes at 64², three frames per transition: a four-frame camera path.
    let frames = page.frames()?;
    page.choose("res", "64")?;
    page.settled(frames)?;
    page.click("#addKey")?;
    let frames = page.frames()?;
    // Clicking may have scrolled the page: find the canvas again.
    let (cx, cy) = page.canvas_centre()?;
    let path: Vec<(f64, f64)> = (1..=6).map(|i| (cx - 20.0 * i as f64, cy)).collect();
    page.drag((cx, cy), &path)?;
    page.settled(frames)?;
    page.click("#addKey")?;
    page.choose("perTransition", "3")?;
    let downloads = scratch.join("downloads");
    std::fs::create_dir_all(&downloads)?;
    page.allow_downloads(&downloads)?;
    page.click("#download")?;
    let camera_path = wait_for_download(&downloads.join("camera_path.json"), deadline)?;
    let out = scratch.join("path");
    render_camera_path(&camera_path, &out, deadline)?;
    let frames_written = frame_files(&out)?;
    ensure!(
        frames_written
            == [
                "frame_0000.png",
                "frame_0001.png",
                "frame_0002.png",
                "frame_0003.png"
            ],
        "the recorded path rendered {frames_written:?}, not 4 frames"
    );
    ensure!(
        out.join("camera_path.gif").is_file(),
        "the recorded path rendered no camera_path.gif"
    );
    println!("recorded camera path rendered: 4 frames and camera_path.gif");

    // Back to 256² for the screenshot.
    let frames = page.frames()?;
    page.choose("res", "256")?;
    page.settled(frames)?;
    if let Some(shot) = std::env::var_os("NERF_BROWSER_SCREENSHOT") {
        let png = page.tab.capture_screenshot(
            Page::CaptureScreenshotFormatOption::Png,
            None,
            None,
            true,
        )?;
        std::fs::write(&shot, png)
            .with_context(|| format!("writing {}", Path::new(&shot).display()))?;
        println!("screenshot: {}", Path::new(&shot).display());
    }
    page.check_errors()
}

/// A running `nerf view --config lego` on a free loopback port, killed when dropped.
struct Server {
    child: Child,
    /// The `http://127.0.0.1:PORT/` address it printed.
    url: String,
}

impl Server {
    /// Starts the server and waits (until `deadline`) for the address on its stdout; the rest
    /// of its stdout is echoed, its stderr goes to the test's.
    fn start(deadline: Instant) -> Result<Server> {
        let mut child = common::nerf_command()
            .args(["view", "--config", "lego", "--port", "0"])
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .context("starting nerf view")?;
        let stdout = child.stdout.take().context("nerf view's stdout")?;
        let mut server = Server {
            child,
            url: String::new(),
        };
        let (tx, rx) = mpsc::channel();
        // Keeps reading so that the server never blocks on a full pipe.
        thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                println!("[nerf view] {line}");
                if let Some(url) = loopback_url(&line) {
                    let _ = tx.send(url);
                }
            }
        });
        server.url = match rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
            Ok(url) => url,
            Err(RecvTimeoutError::Timeout) => bail!("nerf view printed no address in time"),
            Err(RecvTimeoutError::Disconnected) => {
                bail!("nerf view exited without printing its address")
            }
        };
        Ok(server)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The first `http://127.0.0.1:PORT/` in `line`.
fn loopback_url(line: &str) -> Option<String> {
    const PREFIX: &str = "http://127.0.0.1:";
    let start = line.find(PREFIX)?;
    let rest = &line[start + PREFIX.len()..];
    let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
    (digits > 0 && rest[digits..].starts_with('/')).then(|| format!("{PREFIX}{}/", &rest[..digits]))
}

/// Kills the given processes when `deadline` passes, unless dropped before, and ends the test
/// binary (removing the scratch directory `scratch`, which no destructor will) if the test has
/// not finished [`GRACE`] later.
struct Watchdog {
    cancel: Option<mpsc::Sender<()>>,
    thread: Option<JoinHandle<()>>,
}

impl Watchdog {
    fn start(deadline: Instant, pids: Vec<u32>, scratch: PathBuf) -> Watchdog {
        let (cancel, cancelled) = mpsc::channel::<()>();
        let thread = thread::spawn(move || {
            let left = deadline.saturating_duration_since(Instant::now());
            if let Err(RecvTimeoutError::Timeout) = cancelled.recv_timeout(left) {
                eprintln!(
                    "browser test: over {} s; killing the server and the browser",
                    RUN_LIMIT.as_secs()
                );
                for pid in pids {
                    let _ = Command::new("kill")
                        .args(["-KILL", &pid.to_string()])
                        .status();
                }
                // The test's own calls now fail at once, as the browser's connection is gone;
                // should one still be waiting, end the whole test binary.
                if let Err(RecvTimeoutError::Timeout) = cancelled.recv_timeout(GRACE) {
                    eprintln!(
                        "browser test: still running {} s later; exiting",
                        GRACE.as_secs()
                    );
                    let _ = std::fs::remove_dir_all(&scratch);
                    std::process::exit(1);
                }
            }
        });
        Watchdog {
            cancel: Some(cancel),
            thread: Some(thread),
        }
    }
}

impl Drop for Watchdog {
    fn drop(&mut self) {
        drop(self.cancel.take());
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Headless Chromium at `path` with a fresh profile in `profile`; the DevTools port is chosen
/// by Chromium itself (port 0), so it cannot collide with another run's.
fn launch(path: &Path, profile: &Path) -> Result<Browser> {
    let options = LaunchOptions {
        headless: true,
        sandbox: false,
        enable_gpu: false,
        window_size: Some(VIEWPORT),
        port: Some(0),
        path: Some(path.to_path_buf()),
        user_data_dir: Some(profile.to_path_buf()),
        disable_default_args: true,
        args: CHROMIUM_FLAGS.iter().map(std::ffi::OsStr::new).collect(),
        // The transport gives up after this long without a message from the browser; the
        // waits below poll every 100 ms, so it is only reached when the browser hangs.
        idle_browser_timeout: Duration::from_secs(60),
        ..LaunchOptions::default()
    };
    Browser::new(options).with_context(|| format!("launching {}", path.display()))
}

/// The viewer's page in a tab, with the page's uncaught exceptions collected.
struct Viewer {
    tab: Arc<Tab>,
    errors: Arc<Mutex<Vec<String>>>,
    deadline: Instant,
}

impl Viewer {
    fn open(browser: &Browser, url: &str, deadline: Instant) -> Result<Viewer> {
        let tab = browser.new_tab()?;
        tab.set_default_timeout(PAGE_LIMIT);
        // A 960 × 620 page, whatever the window's decorations take (the README's screenshot).
        tab.call_method(Emulation::SetDeviceMetricsOverride {
            width: VIEWPORT.0,
            height: VIEWPORT.1,
            device_scale_factor: 1.0,
            mobile: false,
            scale: None,
            screen_width: None,
            screen_height: None,
            position_x: None,
            position_y: None,
            dont_set_visible_size: None,
            screen_orientation: None,
            viewport: None,
            display_feature: None,
            device_posture: None,
        })?;
        tab.enable_runtime()?;
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = Arc::clone(&errors);
        tab.add_event_listener(Arc::new(move |event: &Event| {
            if let Event::RuntimeExceptionThrown(e) = event {
                let details = &e.params.exception_details;
                let description = details
                    .exception
                    .as_ref()
                    .and_then(|o| o.description.clone())
                    .unwrap_or_else(|| details.text.clone());
                sink.lock().unwrap().push(description);
            }
        }))?;
        tab.navigate_to(url)?.wait_until_navigated()?;
        Ok(Viewer {
            tab,
            errors,
            deadline,
        })
    }

    /// Fails when the page has thrown an uncaught exception.
    fn check_errors(&self) -> Result<()> {
        let errors = self.errors.lock().unwrap();
        ensure!(errors.is_empty(), "page error: {}", errors.join("; "));
        Ok(())
    }

    /// The value of the JavaScript expression `js` (awaited when it is a promise).
    fn eval(&self, js: &str) -> Result<Value> {
        let reply = self.tab.call_method(Runtime::Evaluate {
            expression: js.to_string(),
            return_by_value: Some(true),
            await_promise: Some(true),
            object_group: None,
            include_command_line_api: None,
            silent: None,
            context_id: None,
            generate_preview: None,
            user_gesture: None,
            throw_on_side_effect: None,
            timeout: None,
            disable_breaks: None,
            repl_mode: None,
            allow_unsafe_eval_blocked_by_csp: None,
            unique_context_id: None,
            serialization_options: None,
        })?;
        if let Some(e) = reply.exception_details {
            let description = e.exception.and_then(|o| o.description).unwrap_or(e.text);
            bail!("evaluating {js}: {description}");
        }
        Ok(reply.result.value.unwrap_or(Value::Null))
    }

    fn eval_f64(&self, js: &str) -> Result<f64> {
        let v = self.eval(js)?;
        v.as_f64()
            .with_context(|| format!("{js} gave {v}, not a number"))
    }

    /// The number of full frames drawn so far.
    fn frames(&self) -> Result<u64> {
        Ok(self.eval_f64("window.viewer.frames")? as u64)
    }

    /// The text of the element `id`.
    fn text(&self, id: &str) -> Result<String> {
        let v = self.eval(&format!("document.getElementById('{id}').textContent"))?;
        Ok(v.as_str().unwrap_or_default().to_string())
    }

    /// Waits until the page has drawn the full frame of its newest request, and more than
    /// `after` full frames in all.
    fn settled(&self, after: u64) -> Result<()> {
        let give_up = self.deadline.min(Instant::now() + FRAME_LIMIT);
        let state = "JSON.stringify({frames: window.viewer.frames, gen: window.viewer.gen, \
                     drawnGen: window.viewer.drawnGen, \
                     status: document.getElementById('status').textContent, \
                     error: document.getElementById('error').textContent})";
        loop {
            self.check_errors()?;
            let done = self.eval(&format!(
                "window.viewer.frames > {after} && window.viewer.drawnGen === window.viewer.gen"
            ))?;
            if done == Value::Bool(true) {
                return Ok(());
            }
            if Instant::now() >= give_up {
                bail!(
                    "no new full frame after {after}: {}",
                    self.eval(state).unwrap_or_default()
                );
            }
            thread::sleep(Duration::from_millis(100));
        }
    }

    /// Runs `action` and waits for the full frame it asks for; returns how much the canvas
    /// changed (as [`Viewer::change_since_saved`]).
    fn change_by(&self, action: impl FnOnce(&Self) -> Result<()>) -> Result<f64> {
        self.save_canvas()?;
        let frames = self.frames()?;
        action(self)?;
        self.settled(frames)?;
        self.change_since_saved()
    }

    /// Keeps the canvas's pixels for [`Viewer::change_since_saved`].
    fn save_canvas(&self) -> Result<()> {
        self.eval(
            "(() => { const c = document.getElementById('view'); \
             window.saved = c.getContext('2d').getImageData(0, 0, c.width, c.height).data.slice(); \
             return true; })()",
        )?;
        Ok(())
    }

    /// Mean absolute difference (0..255) between the canvas now and the saved pixels.
    fn change_since_saved(&self) -> Result<f64> {
        self.eval_f64(
            "(() => { const c = document.getElementById('view'); \
             const now = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; \
             const before = window.saved; \
             if (!before || before.length !== now.length) return 255; \
             let sum = 0; for (let i = 0; i < now.length; i++) sum += Math.abs(now[i] - before[i]); \
             return sum / now.length; })()",
        )
    }

    /// The canvas's centre in viewport coordinates (where mouse events land).
    fn canvas_centre(&self) -> Result<(f64, f64)> {
        let v = self.eval(
            "(() => { const r = document.getElementById('view').getBoundingClientRect(); \
             return [r.left + r.width / 2, r.top + r.height / 2]; })()",
        )?;
        match (v[0].as_f64(), v[1].as_f64()) {
            (Some(x), Some(y)) => Ok((x, y)),
            _ => bail!("the canvas has no position: {v}"),
        }
    }

    /// One mouse event at (x, y): `held` says whether the left button is down during it (for
    /// a press, a move while dragging and the release, which is also about the left button).
    fn mouse(
        &self,
        kind: Input::DispatchMouseEventTypeOption,
        (x, y): (f64, f64),
        held: bool,
        delta_y: Option<f64>,
    ) -> Result<()> {
        use Input::DispatchMouseEventTypeOption as Kind;
        let left = held || matches!(kind, Kind::MouseReleased);
        self.tab.call_method(Input::DispatchMouseEvent {
            Type: kind,
            x,
            y,
            modifiers: None,
            timestamp: None,
            button: Some(if left {
                Input::MouseButton::Left
            } else {
                Input::MouseButton::None
            }),
            buttons: Some(u32::from(held)),
            click_count: Some(u32::from(left)),
            force: None,
            tangential_pressure: None,
            tilt_x: None,
            tilt_y: None,
            twist: None,
            delta_x: delta_y.map(|_| 0.0),
            delta_y,
            pointer_Type: None,
        })?;
        Ok(())
    }

    /// Presses the left button at `from`, moves through `path`, releases at its end.
    fn drag(&self, from: (f64, f64), path: &[(f64, f64)]) -> Result<()> {
        use Input::DispatchMouseEventTypeOption as Kind;
        self.mouse(Kind::MouseMoved, from, false, None)?;
        self.mouse(Kind::MousePressed, from, true, None)?;
        for &point in path {
            self.mouse(Kind::MouseMoved, point, true, None)?;
        }
        let end = path.last().copied().unwrap_or(from);
        self.mouse(Kind::MouseReleased, end, false, None)
    }

    /// Turns the wheel by `delta_y` pixels (negative: away from the user, zooming in) at `at`.
    fn wheel(&self, at: (f64, f64), delta_y: f64) -> Result<()> {
        use Input::DispatchMouseEventTypeOption as Kind;
        self.mouse(Kind::MouseMoved, at, false, None)?;
        self.mouse(Kind::MouseWheel, at, false, Some(delta_y))
    }

    /// Clicks the element `selector` with the mouse (scrolled into view first).
    fn click(&self, selector: &str) -> Result<()> {
        self.tab.find_element(selector)?.click()?;
        Ok(())
    }

    /// Sets the form control `id` to `value` and fires `input` and `change`, as a person's
    /// choice would.
    fn choose(&self, id: &str, value: &str) -> Result<()> {
        let done = self.eval(&format!(
            "(() => {{ const e = document.getElementById('{id}'); e.value = '{value}'; \
             e.dispatchEvent(new Event('input', {{ bubbles: true }})); \
             e.dispatchEvent(new Event('change', {{ bubbles: true }})); return e.value; }})()"
        ))?;
        ensure!(done == value, "#{id} took {done}, not {value}");
        Ok(())
    }

    /// Lets downloads land in `dir` under the names the page gives them.
    fn allow_downloads(&self, dir: &Path) -> Result<()> {
        self.tab.call_method(Cdp::SetDownloadBehavior {
            behavior: Cdp::SetDownloadBehaviorBehaviorOption::Allow,
            browser_context_id: None,
            download_path: Some(dir.to_string_lossy().into_owned()),
            events_enabled: None,
        })?;
        Ok(())
    }
}

/// Waits (until `deadline`, at most 30 s) for the downloaded camera path at `path`, and checks
/// that it is complete JSON with the expected 4 poses between two different keyframes (the
/// drag between them moved the camera).
fn wait_for_download(path: &Path, deadline: Instant) -> Result<PathBuf> {
    let give_up = deadline.min(Instant::now() + Duration::from_secs(30));
    loop {
        let parsed = std::fs::read(path)
            .ok()
            .and_then(|bytes| serde_json::from_slice::<Value>(&bytes).ok());
        if let Some(json) = parsed {
            let poses = json["camera_path"].as_array().map_or(0, Vec::len);
            ensure!(
                poses == 4,
                "the downloaded camera path has {poses} poses, not 4"
            );
            let keys = json["keyframes"].as_array().map(Vec::as_slice);
            ensure!(
                matches!(keys, Some([a, b]) if a != b),
                "the downloaded camera path does not have two different keyframes: {}",
                json["keyframes"]
            );
            return Ok(path.to_path_buf());
        }
        if Instant::now() >= give_up {
            bail!("no camera path downloaded to {}", path.display());
        }
        thread::sleep(Duration::from_millis(100));
    }
}

/// `nerf render --config lego --camera-path FILE --out-dir OUT`, stopped at `deadline`.
fn render_camera_path(camera_path: &Path, out: &Path, deadline: Instant) -> Result<()> {
    let mut child = common::nerf_command()
        .args(["render", "--config", "lego", "--camera-path"])
        .arg(camera_path)
        .arg("--out-dir")
        .arg(out)
        .spawn()
        .context("starting nerf render")?;
    loop {
        if let Some(status) = child.try_wait()? {
            ensure!(
                status.success(),
                "nerf render --camera-path failed: {status}"
            );
            return Ok(());
        }
        if Instant::now() >= deadline {
            let _ = child.kill();
            let _ = child.wait();
            bail!("nerf render --camera-path ran past the deadline");
        }
        thread::sleep(Duration::from_millis(100));
    }
}

/// The sorted names of the `frame_*.png` files in `dir`.
fn frame_files(dir: &Path) -> Result<Vec<String>> {
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let name = entry?.file_name().to_string_lossy().into_owned();
        if name.starts_with("frame_") && name.ends_with(".png") {
            names.push(name);
        }
    }
    names.sort();
    Ok(names)
}

/// The number in `text` between `prefix` and `suffix` on one line, if there is one.
fn number_between(text: &str, prefix: &str, suffix: &str) -> Option<f64> {
    text.lines().find_map(|line| {
        let rest = &line[line.find(prefix)? + prefix.len()..];
        rest[..rest.find(suffix)?].trim().parse().ok()
    })
}

#[test]
fn status_and_address_parsing() {
    let status = "256 × 256 full\nframe time 0.412 s\nsamples evaluated 17.5 %";
    assert_eq!(number_between(status, "frame time ", " s"), Some(0.412));
    assert_eq!(
        number_between(status, "samples evaluated ", " %"),
        Some(17.5)
    );
    assert_eq!(number_between("loading…", "frame time ", " s"), None);
    assert_eq!(
        loopback_url("nerf view: lego at http://127.0.0.1:40123/ (Ctrl-C to stop)").as_deref(),
        Some("http://127.0.0.1:40123/")
    );
    assert_eq!(loopback_url("listening on http://0.0.0.0:80/"), None);
}
