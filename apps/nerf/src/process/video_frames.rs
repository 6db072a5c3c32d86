//! `nerf process --video FILE`: the frames of a video to reconstruct from, through ffmpeg (`ffmpeg`
//! on `PATH`, or the executable `NERF_FFMPEG` names; Debian's `ffmpeg` package). Candidate
//! frames spread evenly over the clip ([`CANDIDATES_PER_FRAME`] per frame kept, at most every
//! frame of the clip) are streamed from ffmpeg as small grey thumbnails and scored
//! ([`crate::process::frame_selection::laplacian_variance`]); the sharpest of each stretch
//! ([`crate::process::frame_selection::sharpest_per_stretch`]) is then written at full size as a
//! JPEG by a second ffmpeg pass over the same candidates. Nothing but the scores is held in
//! memory, and ffmpeg is stopped after twice the candidates asked for, whatever the file says
//! its length is.

use crate::process::external_tool::ExternalTool;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{anyhow, bail, Context, Result};

use crate::process::frame_selection::{laplacian_variance, sharpest_per_stretch};
use nerf::io::progress::progress_bar;

/// The environment variable naming the ffmpeg executable (default: `ffmpeg` on `PATH`).
pub const FFMPEG_ENV: &str = "NERF_FFMPEG";

/// Frames kept from a video when `--frames` is not given (see docs/own-scene.md for the
/// timings behind it).
pub const DEFAULT_FRAMES: usize = 100;

/// Candidate frames scored per frame kept.
pub const CANDIDATES_PER_FRAME: usize = 4;

/// The grey thumbnails scored: width and height (the clip's aspect is not kept; the score
/// only ranks frames of one clip).
const THUMBNAIL: (usize, usize) = (192, 144);

/// What ffmpeg says about a video.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoProbe {
    /// Seconds.
    pub duration: f64,
    /// Frames per second of its video stream, when ffmpeg says.
    pub fps: Option<f64>,
}

/// The ffmpeg executable: `$NERF_FFMPEG` when set, else `ffmpeg` (looked up on `PATH`).
pub fn ffmpeg_program() -> PathBuf {
    std::env::var_os(FFMPEG_ENV)
        .filter(|v| !v.is_empty())
        .map_or_else(|| PathBuf::from("ffmpeg"), PathBuf::from)
}

/// Checks that `program` runs (`ffmpeg -version`); the one-line error says that ffmpeg is
/// missing and how to install it.
pub fn check_ffmpeg(program: &Path) -> Result<()> {
    let ffmpeg = ExternalTool {
        name: "ffmpeg",
        env: FFMPEG_ENV,
        package: "ffmpeg",
    };
    let mut command = Command::new(program);
    command.arg("-version");
    ffmpeg.check(command, program)
}

/// The duration and frame rate in ffmpeg's description of an input (`ffmpeg -i FILE`'s
/// stderr): `Duration: HH:MM:SS.ss` and the `N fps` of the first `Video:` stream. `None`
/// when it names no video stream or no finite positive duration (a still image reads as a
/// video stream of no duration).
pub fn parse_probe(text: &str) -> Option<VideoProbe> {
    let video = text
        .lines()
        .find(|l| l.trim_start().starts_with("Stream #") && l.contains("Video:"))?;
    let duration = text.lines().find_map(|l| {
        let rest = l.trim_start().strip_prefix("Duration:")?;
        let clock = rest.split(',').next()?.trim();
        let mut seconds = 0.0;
        for part in clock.split(':') {
            seconds = 60.0 * seconds + part.parse::<f64>().ok()?;
        }
        Some(seconds)
    })?;
    if !(duration.is_finite() && duration > 0.0) {
        return None;
    }
    let fps = video.split(',').find_map(|part| {
        let number = part.trim().strip_suffix(" fps")?;
        let value = number.trim().parse::<f64>().ok()?;
        (value.is_finite() && value > 0.0).then_some(value)
    });
    Some(VideoProbe { duration, fps })
}

/// What ffmpeg makes of `video`; the one-line error names the file and ffmpeg's complaint
/// when it is not a video ffmpeg can read.
pub fn probe(program: &Path, video: &Path) -> Result<VideoProbe> {
    let output = Command::new(program)
        .arg("-hide_banner")
        .arg("-i")
        .arg(video)
        .stdin(Stdio::null())
        .output()
        .with_context(|| format!("cannot run ffmpeg ({})", program.display()))?;
    let text = String::from_utf8_lossy(&output.stderr);
    parse_probe(&text).ok_or_else(|| {
        let complaint = text
            .lines()
            .rev()
            .map(str::trim)
            .find(|l| !l.is_empty() && !l.starts_with("At least one output file"))
            .unwrap_or("no video stream of known length");
        anyhow!(
            "--video {}: not a video ffmpeg can read ({complaint})",
            video.display()
        )
    })
}

/// Candidate frames to score: `CANDIDATES_PER_FRAME·frames`, but no more than the clip holds
/// (`duration·fps`, when known; then fewer than `frames` may be kept), and at least one.
pub fn candidate_count(probe: &VideoProbe, frames: usize) -> usize {
    let wanted = frames.saturating_mul(CANDIDATES_PER_FRAME);
    let held = probe
        .fps
        .map_or(usize::MAX, |fps| (probe.duration * fps).floor() as usize);
    wanted.min(held).max(1)
}

/// ffmpeg reading `video` with the candidates' filter (`fps=RATE`) followed by `then`.
fn ffmpeg_over_candidates(program: &Path, video: &Path, rate: f64, then: &str) -> Command {
    let mut command = Command::new(program);
    command
        .args(["-hide_banner", "-loglevel", "error", "-nostdin", "-i"])
        .arg(video)
        .arg("-vf")
        .arg(format!("fps={rate:.6},{then}"))
        .stdin(Stdio::null());
    command
}

/// Scores of the candidate frames ffmpeg streams at `rate` per second as grey thumbnails
/// ([`laplacian_variance`]), in order; at most `2·expected + 10` are read.
fn score_candidates(program: &Path, video: &Path, rate: f64, expected: usize) -> Result<Vec<f64>> {
    let (w, h) = THUMBNAIL;
    let mut child = ffmpeg_over_candidates(program, video, rate, &format!("scale={w}:{h}"))
        .args(["-pix_fmt", "gray", "-f", "rawvideo", "-"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .with_context(|| format!("cannot run ffmpeg ({})", program.display()))?;
    let mut stdout = child.stdout.take().expect("piped stdout");
    let mut stderr = child.stderr.take().expect("piped stderr");
    let errors = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = stderr.read_to_string(&mut text);
        text
    });
    let bar = progress_bar(expected as u64, "scoring video frames");
    let limit = 2 * expected + 10;
    let mut frame = vec![0u8; w * h];
    let mut grey = vec![0f32; w * h];
    let mut scores = Vec::new();
    while scores.len() < limit {
        match stdout.read_exact(&mut frame) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => break,
            Err(e) => return Err(e).context("cannot read ffmpeg's frames"),
        }
        for (g, &b) in grey.iter_mut().zip(&frame) {
            *g = f32::from(b) / 255.0;
        }
        scores.push(laplacian_variance(&grey, w, h));
        bar.inc(1);
    }
    bar.finish_and_clear();
    drop(stdout);
    if scores.len() >= limit {
        let _ = child.kill();
    }
    let status = child.wait().context("ffmpeg did not finish")?;
    let complaint = errors.join().unwrap_or_default();
    if scores.is_empty() {
        bail!(
            "--video {}: ffmpeg gave no frames ({status}; {})",
            video.display(),
            complaint.lines().last().unwrap_or("no message").trim()
        );
    }
    Ok(scores)
}

/// Writes candidates `chosen` (indices among those at `rate` per second) of `video` as
/// `dir/frame_00000.jpg`, ... in order.
fn write_chosen(
    program: &Path,
    video: &Path,
    rate: f64,
    chosen: &[usize],
    dir: &Path,
) -> Result<()> {
    let select: Vec<String> = chosen.iter().map(|i| format!("eq(n\\,{i})")).collect();
    let pattern = dir.join("frame_%05d.jpg");
    let output = ffmpeg_over_candidates(
        program,
        video,
        rate,
        &format!("select='{}'", select.join("+")),
    )
    // Each selected frame written once: ffmpeg's image sequences otherwise keep the
    // clip's frame rate, repeating frames to fill the gaps (`-vsync` works on ffmpeg 4
    // to 7; `-fps_mode` only from 5.1).
    .args(["-vsync", "passthrough", "-q:v", "2", "-start_number", "0"])
    .arg(&pattern)
    .output()
    .with_context(|| format!("cannot run ffmpeg ({})", program.display()))?;
    if !output.status.success() {
        let text = String::from_utf8_lossy(&output.stderr);
        bail!(
            "ffmpeg could not write the frames of {} ({}): {}",
            video.display(),
            output.status,
            text.lines().last().unwrap_or("no message").trim()
        );
    }
    Ok(())
}

/// How many frames were chosen from how many candidates.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameChoice {
    /// Candidate frames scored.
    pub candidates: usize,
    /// Frames written.
    pub frames: usize,
    /// The clip's length, seconds.
    pub duration: f64,
}

/// Writes `frames` frames of `video` (as [`probe`] found it: the sharpest of each stretch of
/// candidates spread over the clip, see the module) as JPEGs into `images`, through
/// `images.partial` (replaced if there) renamed into place at the end, so `images` either
/// holds all of them or does not exist. One-line errors: ffmpeg failing, fewer frames
/// written than chosen.
pub fn extract_frames(
    program: &Path,
    video: &Path,
    probe: &VideoProbe,
    frames: usize,
    images: &Path,
) -> Result<FrameChoice> {
    let expected = candidate_count(probe, frames);
    let rate = expected as f64 / probe.duration;
    log::info!(
        "{}: {:.1} s{}; scoring {expected} candidate frames for {frames}",
        video.display(),
        probe.duration,
        probe
            .fps
            .map_or(String::new(), |f| format!(" at {f:.2} fps"))
    );
    let scores = score_candidates(program, video, rate, expected)?;
    let chosen = sharpest_per_stretch(&scores, frames);
    let partial = images.with_extension("partial");
    if partial.symlink_metadata().is_ok() {
        std::fs::remove_dir_all(&partial)
            .with_context(|| format!("cannot remove {}", partial.display()))?;
    }
    std::fs::create_dir_all(&partial)
        .with_context(|| format!("cannot create {}", partial.display()))?;
    write_chosen(program, video, rate, &chosen, &partial)?;
    let written = std::fs::read_dir(&partial)
        .with_context(|| format!("cannot list {}", partial.display()))?
        .count();
    if written != chosen.len() {
        bail!(
            "ffmpeg wrote {written} of the {} frames chosen from {} (in {})",
            chosen.len(),
            video.display(),
            partial.display()
        );
    }
    std::fs::rename(&partial, images)
        .with_context(|| format!("cannot move {} to {}", partial.display(), images.display()))?;
    Ok(FrameChoice {
        candidates: scores.len(),
        frames: written,
        duration: probe.duration,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn probes_read_duration_and_rate_or_refuse() {
        let clip = "Input #0, mov,mp4,m4a,3gp,3g2,mj2, from 'a.mp4':\n  Duration: 00:01:02.50, start: 0.000000, bitrate: 120 kb/s\n  Stream #0:0[0x1](und): Video: h264 (High) (avc1 / 0x31637661), yuv420p(progressive), 64x48, 100 kb/s, 29.97 fps, 29.97 tbr, 30k tbn (default)\nAt least one output file must be specified";
        let p = parse_probe(clip).unwrap();
        assert!((p.duration - 62.5).abs() < 1e-9);
        assert_eq!(p.fps, Some(29.97));
        assert_eq!(candidate_count(&p, 100), 400);
        assert_eq!(candidate_count(&p, 1000), 1873);
        assert_eq!(candidate_count(&p, 3000), 1873);
        let still = "Input #0, png_pipe, from 'a.png':\n  Duration: N/A, bitrate: N/A\n  Stream #0:0: Video: png, rgb24(pc), 8x8, 25 fps, 25 tbr, 25 tbn";
        assert_eq!(parse_probe(still), None);
        let audio = "Input #0, wav, from 'a.wav':\n  Duration: 00:00:03.00, bitrate: 705 kb/s\n  Stream #0:0: Audio: pcm_s16le, 44100 Hz, 1 channels";
        assert_eq!(parse_probe(audio), None);
        assert_eq!(
            parse_probe("a.txt: Invalid data found when processing input"),
            None
        );
    }
}
