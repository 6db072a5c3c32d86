//! `nerf render --camera-path`: a nerfstudio camera path rendered as PNG frames, a GIF and,
//! when ffmpeg is on PATH, an MP4.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, ensure, Result};
use candle_core::Device;

use crate::render::scene::load_scene_field;
use nerf::config::{limits, Config};
use nerf::io::camera_path::{read_camera_path, CameraPath};
use nerf::io::images::{write_gif, write_png};
use nerf::io::output::{prepare_out_dir, remove_stale_temp_files, write_through_path};
use nerf::io::progress::progress_bar;
use nerf::render::view::render_view;

/// Refuses paths past the config limits (image side, frame count, pixels over all frames, as
/// the surround views are limited).
fn check_limits(path: &CameraPath) -> Result<()> {
    let (w, h, n) = (path.width, path.height, path.cameras.len());
    ensure!(
        w <= limits::IMAGE_SIDE && h <= limits::IMAGE_SIDE,
        "render_width and render_height must be at most {} (got {w}×{h})",
        limits::IMAGE_SIDE
    );
    ensure!(
        n <= limits::POSES,
        "camera_path has {n} frames, more than the {} allowed",
        limits::POSES
    );
    ensure!(
        n * w * h <= limits::FRAME_PIXELS,
        "{n} frames of {w}×{h} are more than {} pixels in all",
        limits::FRAME_PIXELS
    );
    Ok(())
}

/// `ffmpeg` when it is an executable file on PATH.
fn ffmpeg() -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|dir| dir.join("ffmpeg"))
        .find(|p| p.is_file())
}

/// Encodes `frame_%04d.png` in `out_dir` as `camera_path.mp4` (H.264 where ffmpeg has it,
/// sides padded to even numbers as yuv420p needs), by the one writing rule (ffmpeg fills a
/// temporary file beside the real target, which is then renamed over it).
fn encode_mp4(ffmpeg: &Path, out_dir: &Path, fps: f64) -> Result<PathBuf> {
    let mp4 = out_dir.join("camera_path.mp4");
    write_through_path(&mp4, |tmp| {
        let status = Command::new(ffmpeg)
            .args([
                "-y",
                "-loglevel",
                "error",
                "-framerate",
                &format!("{fps}"),
                "-i",
            ])
            .arg(out_dir.join("frame_%04d.png"))
            .args([
                "-vf",
                "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                "-pix_fmt",
                "yuv420p",
            ])
            .args(["-f", "mp4"])
            .arg(tmp)
            .status();
        match status {
            Ok(s) if s.success() => Ok(()),
            other => bail!("ffmpeg could not encode {}: {other:?}", mp4.display()),
        }
    })?;
    Ok(mp4)
}

/// Renders every camera of the path at `path`: `frame_0000.png`, …, `camera_path.gif` and,
/// when ffmpeg is on PATH, `camera_path.mp4` in `out_dir`. Returns the files written.
pub fn render_camera_path(
    config: &Config,
    checkpoint: Option<&Path>,
    path: &Path,
    out_dir: &Path,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    let camera_path = read_camera_path(path)?;
    check_limits(&camera_path)?;
    let scene = load_scene_field(config, checkpoint, device)?;
    prepare_out_dir(out_dir)?;
    let render = config.render_settings()?;
    let size = (camera_path.width, camera_path.height);
    let bar = progress_bar(camera_path.cameras.len() as u64, "camera path");
    let mut frames = Vec::new();
    let mut written = Vec::new();
    for (i, camera) in camera_path.cameras.iter().enumerate() {
        let view = render_view(
            &render.with(scene.as_field()),
            &nerf::Camera::from(*camera),
            size,
            device,
        )?;
        let png = out_dir.join(format!("frame_{i:04}.png"));
        write_png(&png, &view.color)?;
        written.push(png);
        frames.push(view.color);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let gif = out_dir.join("camera_path.gif");
    // GIF delays are whole hundredths of a second.
    let delay = (100.0 / camera_path.fps)
        .round()
        .clamp(1.0, u16::MAX as f64) as u16;
    write_gif(&gif, &frames, delay)?;
    written.push(gif);
    match ffmpeg() {
        Some(ffmpeg) => {
            remove_stale_temp_files(&out_dir.join("camera_path.mp4"));
            written.push(encode_mp4(&ffmpeg, out_dir, camera_path.fps)?);
        }
        None => eprintln!("ffmpeg is not on PATH: no MP4 (the PNG frames and the GIF are written)"),
    }
    Ok(written)
}
