//! `nerf process --video`: frames picked from a clip (the sharpest of each stretch), matched
//! in order, and a video's bad inputs as one-line errors.

mod common;

use std::path::Path;
use std::process::{Command, Output};

use common::process_tools::*;
use nerf::core::camera::alignment::CameraPair;

/// Whether ffmpeg runs here (`ffmpeg` on PATH, or `$NERF_FFMPEG`); else a visible skip, and a
/// failure under `CI=true` ([`tool_installed`]).
fn ffmpeg_installed() -> bool {
    tool_installed("ffmpeg", ("NERF_FFMPEG", "ffmpeg", "-version"), "ffmpeg")
}

/// Encodes `dir/<pattern>` (an ffmpeg image sequence, numbered from 0) at `fps` frames a
/// second into `out` (H.264 in MP4, as a phone records), with `filter` applied.
fn encode_video(dir: &Path, pattern: &str, fps: u32, filter: &str, out: &Path) {
    let program = std::env::var_os("NERF_FFMPEG").unwrap_or_else(|| "ffmpeg".into());
    let o = Command::new(program)
        .args(["-hide_banner", "-loglevel", "error", "-y", "-framerate"])
        .arg(fps.to_string())
        .args(["-start_number", "0", "-i"])
        .arg(dir.join(pattern))
        .args(["-vf", filter])
        .args(["-c:v", "libx264", "-crf", "18", "-pix_fmt", "yuv420p"])
        .arg(out)
        .output()
        .expect("run ffmpeg");
    assert!(o.status.success(), "{}", common::stderr(&o));
}

/// The grey values of the image at `path`, resized to 48×36.
fn grey_thumbnail(path: &Path) -> Vec<f32> {
    let image = image::open(path).unwrap().to_luma8();
    image::imageops::resize(&image, 48, 36, image::imageops::FilterType::Triangle)
        .pixels()
        .map(|p| f32::from(p.0[0]))
        .collect()
}

/// The index of the image in `sources` (grey thumbnails) nearest to `frame`'s by mean
/// absolute difference.
fn nearest_source(frame: &Path, sources: &[Vec<f32>]) -> usize {
    let grey = grey_thumbnail(frame);
    let distance = |s: &Vec<f32>| grey.iter().zip(s).map(|(a, b)| (a - b).abs()).sum::<f32>();
    (0..sources.len())
        .min_by(|&a, &b| distance(&sources[a]).total_cmp(&distance(&sources[b])))
        .unwrap()
}

/// `nerf process --video VIDEO --out OUT` with `extra` arguments and `env` variables.
fn process_video(video: &Path, out: &Path, extra: &[&str], env: &[(&str, &Path)]) -> Output {
    let mut command = common::nerf_command();
    command
        .args(["process", "--video"])
        .arg(video)
        .arg("--out")
        .arg(out)
        .args(extra);
    for (k, v) in env {
        command.env(k, v);
    }
    command.output().expect("run nerf")
}

#[test]
fn video_frames_are_the_sharpest_of_each_stretch_and_matched_sequentially() {
    let _alone = alone();
    if !ffmpeg_installed() {
        return;
    }
    // 40 frames of a texture sliding 3 px a frame; in each run of 4, one sharp frame (at a
    // place that moves from run to run) and three blurred. At 10 fps and 10 frames kept,
    // the candidates are the clip's 40 frames and the stretches these runs of 4.
    let (dir, frames) = common::scratch("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let texture = image::RgbImage::from_fn(400, 120, |x, y| {
        let v = ((x / 6 * 7919 + y / 6 * 104_729) % 251) as u8;
        image::Rgb([v, 255 - v, v / 2])
    });
    let mut sharp = Vec::new();
    let mut sources = Vec::new();
    for i in 0..40u32 {
        let mut frame = image::imageops::crop_imm(&texture, 3 * i, 0, 160, 120).to_image();
        let is_sharp = i % 4 == (i / 4) % 4;
        if !is_sharp {
            frame = image::imageops::blur(&frame, 2.5);
        }
        let path = frames.join(format!("f_{i:03}.png"));
        frame.save(&path).unwrap();
        sharp.push(is_sharp);
        sources.push(grey_thumbnail(&path));
    }
    let video = dir.path().join("clip.mp4");
    encode_video(&frames, "f_%03d.png", 10, "null", &video);

    let names: Vec<String> = (0..10).map(|i| format!("frame_{i:05}.jpg")).collect();
    let models = ring_models(dir.path(), &names, "none", 3);
    let colmap = seeded_colmap(dir.path(), &models, "echo \"$@\"\n", COPY_INPUT);
    let tree = dir.path().join("tree.bin");
    std::fs::write(&tree, "a vocabulary tree").unwrap();
    let out = dir.path().join("capture");
    let extra = ["--frames", "10", "--vocab-tree", tree.to_str().unwrap()];
    let o = process_video(&video, &out, &extra, &[("NERF_COLMAP", &colmap)]);
    let stdout = common::succeeded_stdout(&o);
    assert!(stdout.contains("10 of 10 images registered"), "{stdout}");
    let written = common::sorted_names(&out.join("images"));
    assert_eq!(written, names);
    for name in &written {
        let source = nearest_source(&out.join("images").join(name), &sources);
        assert!(sharp[source], "{name} is frame {source}, a blurred one");
    }
    // Sequential matching, with loop detection on the given tree.
    let log = std::fs::read_to_string(out.join("colmap/sequential_matcher.log")).unwrap();
    assert!(
        log.contains("--SequentialMatching.loop_detection 1")
            && log.contains("--SequentialMatching.vocab_tree_path"),
        "{log}"
    );
    assert!(!out.join("images.partial").exists());
    assert_eq!(written_frames(&out).len(), 10);

    // A clip shorter than the frames asked for: every frame is kept, once (and a COLMAP
    // that registers nothing leaves them there, with no transforms.json).
    let idle_dir = dir.path().join("idle");
    std::fs::create_dir_all(&idle_dir).unwrap();
    let idle = fake_colmap(&idle_dir, "exit 0");
    let out = dir.path().join("all");
    let o = process_video(&video, &out, &["--frames", "60"], &[("NERF_COLMAP", &idle)]);
    let err = last_line_error(&o);
    assert!(err.contains("COLMAP registered 0 of 40 images"), "{err}");
    assert_eq!(common::sorted_names(&out.join("images")).len(), 40);
    assert!(!out.join("transforms.json").exists());
}

#[test]
fn bad_video_inputs_are_one_line_errors() {
    let _alone = alone();
    let (dir, out) = common::scratch("out");
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "not a video").unwrap();
    let still = dir.path().join("still.png");
    image::RgbImage::from_pixel(8, 8, image::Rgb([9, 9, 9]))
        .save(&still)
        .unwrap();
    let idle = fake_colmap(dir.path(), "exit 0");
    let colmap = [("NERF_COLMAP", idle.as_path())];

    let missing = dir.path().join("missing.mp4");
    let err = common::one_line_error(&process_video(&missing, &out, &[], &colmap));
    assert!(err.contains("missing.mp4: not a file"), "{err}");
    let nowhere = [
        ("NERF_COLMAP", idle.as_path()),
        ("NERF_FFMPEG", Path::new("/nonexistent/ffmpeg")),
    ];
    let err = common::one_line_error(&process_video(&text, &out, &[], &nowhere));
    assert!(
        err.contains("ffmpeg is missing") && err.contains("sudo apt-get install ffmpeg"),
        "{err}"
    );
    let tree = dir.path().join("no_tree.bin");
    let extra = ["--vocab-tree", tree.to_str().unwrap()];
    let err = common::one_line_error(&process_video(&text, &out, &extra, &colmap));
    assert!(err.contains("no_tree.bin: not a file"), "{err}");
    assert!(!out.exists());

    if ffmpeg_installed() {
        for file in [&text, &still] {
            let err = common::one_line_error(&process_video(file, &out, &[], &colmap));
            assert!(err.contains("not a video ffmpeg can read"), "{err}");
            assert!(!out.exists(), "{err}");
        }
    }

    // Usage errors: both sources, neither, --frames out of range or without --video.
    let v = text.to_str().unwrap();
    for args in [
        &["--images", "x", "--video", v][..],
        &[][..],
        &["--video", v, "--frames", "2"][..],
        &["--images", "x", "--frames", "10"][..],
    ] {
        let o = common::nerf(&[&["process", "--out", "y"][..], args].concat());
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", common::stderr(&o));
    }
}

/// With COLMAP 3.8 this registered 13 of the 20 frames in its first full run; with COLMAP 4
/// through pycolmap, 20 of 20 in four runs of four (centres within 1.45–1.55% of the radius).
#[test]
fn colmap_recovers_lego_cameras_from_a_video() {
    let _alone = alone();
    let Some(lego) = common::lego_dir() else {
        return;
    };
    if !pycolmap_installed() || !ffmpeg_installed() {
        return;
    }
    // Lego's first 60 test views on white (a 216° arc coming down from 47° to 25° of
    // elevation) as a 10 fps clip, of which 20 frames are kept.
    let truth = lego_cameras(&lego, "test");
    let (dir, frames) = common::scratch("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let mut sources = Vec::new();
    for (i, (name, _, _)) in truth.iter().take(60).enumerate() {
        let rgba = image::open(lego.join("test").join(name))
            .unwrap()
            .to_rgba8();
        let white = image::RgbImage::from_fn(rgba.width(), rgba.height(), |x, y| {
            let p = rgba.get_pixel(x, y).0;
            let a = f32::from(p[3]) / 255.0;
            let over_white = |c: u8| (f32::from(c) * a + 255.0 * (1.0 - a)).round() as u8;
            image::Rgb([over_white(p[0]), over_white(p[1]), over_white(p[2])])
        });
        let path = frames.join(format!("v_{i:03}.png"));
        white.save(&path).unwrap();
        sources.push(grey_thumbnail(&path));
    }
    let video = dir.path().join("orbit.mp4");
    encode_video(&frames, "v_%03d.png", 10, "scale=400:400", &video);
    let out = dir.path().join("capture");
    timed_ok("--video on 60 lego test views", || {
        process_video(&video, &out, &["--frames", "20", "--sfm", "pycolmap"], &[])
    });

    let frames = written_frames(&out);
    assert!(frames.len() >= 15, "{} of 20 registered", frames.len());
    let pairs: Vec<CameraPair> = frames
        .iter()
        .map(|f| {
            let path = f["file_path"].as_str().unwrap();
            let source = nearest_source(&out.join(path), &sources);
            let (_, true_rotation, true_centre) = truth[source].clone();
            let (rotation, centre) = rotation_and_centre(&f["transform_matrix"]);
            CameraPair {
                true_rotation,
                true_centre,
                rotation,
                centre,
            }
        })
        .collect();
    assert_aligned(&pairs);
}
