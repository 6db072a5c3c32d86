//! Lego's 100 NeRF-synthetic training renders as photos without alpha: each composited on
//! white and written as a JPEG (quality 95), `OUT/images/r_N.jpg`: what a camera would have
//! taken of the model on a white backdrop, the input of issue 22's `nerf process` criterion.
//! With `--transforms` it also writes `OUT/transforms.json`, a nerfstudio capture with the
//! renders' true cameras (OPENCV, no distortion), to train on without structure from motion.
//!
//! Run: `cargo run --release --example lego_photos -- LEGO_DIR OUT [--transforms]`
//! (LEGO_DIR: the NeRF-synthetic lego, `../shared/data/lego`).

use std::path::Path;

use anyhow::{bail, Context, Result};

/// One training view: its image stem (`r_N`) and camera → world matrix (OpenGL axes).
fn training_views(lego: &Path) -> Result<(f64, Vec<(String, serde_json::Value)>)> {
    let path = lego.join("transforms_train.json");
    let text = std::fs::read_to_string(&path).with_context(|| path.display().to_string())?;
    let json: serde_json::Value = serde_json::from_str(&text)?;
    let fov = json["camera_angle_x"]
        .as_f64()
        .context("camera_angle_x missing")?;
    let frames = json["frames"].as_array().context("frames missing")?;
    let views = frames
        .iter()
        .map(|f| {
            let file = f["file_path"].as_str().context("file_path missing")?;
            let stem = file.rsplit('/').next().unwrap_or(file).to_string();
            Ok((stem, f["transform_matrix"].clone()))
        })
        .collect::<Result<_>>()?;
    Ok((fov, views))
}

/// `src` (RGBA PNG) over white, written to `dst` as a JPEG.
fn white_jpeg(src: &Path, dst: &Path) -> Result<(u32, u32)> {
    let rgba = image::open(src)
        .with_context(|| src.display().to_string())?
        .to_rgba8();
    let (w, h) = rgba.dimensions();
    let rgb = image::RgbImage::from_fn(w, h, |x, y| {
        let p = rgba.get_pixel(x, y).0;
        let a = f32::from(p[3]) / 255.0;
        image::Rgb(std::array::from_fn(|c| {
            (f32::from(p[c]) * a + 255.0 * (1.0 - a)).round() as u8
        }))
    });
    let tmp = dst.with_extension("jpg.tmp");
    let mut file = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut file, 95).encode_image(&rgb)?;
    drop(file);
    std::fs::rename(&tmp, dst)?;
    Ok((w, h))
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let with_transforms = args.iter().any(|a| a == "--transforms");
    let paths: Vec<&String> = args.iter().filter(|a| !a.starts_with("--")).collect();
    let [lego, out] = paths[..] else {
        bail!("usage: lego_photos LEGO_DIR OUT [--transforms]");
    };
    let (lego, out) = (Path::new(lego), Path::new(out));
    let (fov, views) = training_views(lego)?;
    std::fs::create_dir_all(out.join("images"))?;
    let mut frames = Vec::new();
    let mut size = (0, 0);
    for (stem, c2w) in &views {
        let name = format!("images/{stem}.jpg");
        size = white_jpeg(
            &lego.join("train").join(format!("{stem}.png")),
            &out.join(&name),
        )?;
        frames.push(serde_json::json!({"file_path": name, "transform_matrix": c2w}));
    }
    if with_transforms {
        let (w, h) = size;
        let focal = 0.5 * w as f64 / (0.5 * fov).tan();
        let json = serde_json::json!({
            "camera_model": "OPENCV", "fl_x": focal, "fl_y": focal,
            "cx": w as f64 / 2.0, "cy": h as f64 / 2.0, "w": w, "h": h, "frames": frames,
        });
        std::fs::write(out.join("transforms.json"), json.to_string())?;
    }
    println!("{} photos in {}", views.len(), out.join("images").display());
    Ok(())
}
