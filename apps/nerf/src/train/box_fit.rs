//! The homework's `train` job (`type: train`, e.g. `train_box.yaml`): fit an SDF volume's
//! `opt: True` parameters to the images of `data.cameras`, and `nerf targets`, which renders
//! those images from a volume of the user's choosing.
//!
//! Everything is read and checked (config, cameras, every target `.npy`) before anything is
//! written. Then, as the homework's `main.py` does: `render_box_before_training_{i}.png` for
//! each training camera, the fit (progress bar with the loss), `render_box_after_training_{i}.png`,
//! and `render_box.gif` (the config's surround views: 20 at radius 3 for an SDF scene), plus
//! `sdf_fit.json` with the fitted parameters.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use candle_core::Device;
use serde_json::json;

use crate::render::scene::render_views;
use nerf::config::Config;
use nerf::core::camera::PerspectiveCamera;
use nerf::core::sdf::{Sdf, SdfVolume};
use nerf::field::trainable::TrainableField;
use nerf::io::images::{write_gif, write_npy, write_png};
use nerf::io::npy::read_npy_image;
use nerf::io::output::{prepare_out_dir, write_text};
use nerf::render::field::Field;
use nerf::render::view::Pipeline;
use nerf::train::fit_sdf::{fit_sdf, SdfFitReport, SdfView};

/// What a fit produced.
#[derive(Debug, Clone)]
pub struct SdfFitOutcome {
    /// The parameters before training.
    pub initial: SdfVolume,
    /// The fitted parameters.
    pub fitted: SdfVolume,
    /// Names of the trained parameters.
    pub trained: Vec<String>,
    /// Steps, losses and time of the loop.
    pub report: SdfFitReport,
    /// Files written.
    pub written: Vec<PathBuf>,
}

/// The training views of `config`: each `data.cameras` camera with its `image` read (paths
/// relative to the working directory); an error names the camera or file at fault.
pub fn load_training_views(config: &Config) -> Result<Vec<SdfView>> {
    let (w, h) = config.image_size();
    config
        .data_cameras()?
        .into_iter()
        .map(|(name, camera, image)| {
            let path = image.with_context(|| {
                format!("data.cameras.{name}.image: missing (the target image of this camera)")
            })?;
            let image = read_npy_image(&path, w, h).map_err(|e| {
                let hint = if path.exists() {
                    String::new()
                } else {
                    " (make the targets with `nerf targets --config <this config>` and overrides giving the box to recover; see docs/homework.md)".to_string()
                };
                anyhow::anyhow!("data.cameras.{name}.image: {e:#}{hint}")
            })?;
            Ok(SdfView { camera, image })
        })
        .collect()
}

/// Renders the views of `cameras` and writes `<prefix>_{i}.png` for each into `out_dir`.
fn write_views(
    config: &Config,
    field: &dyn Field,
    cameras: &[PerspectiveCamera],
    out_dir: &Path,
    prefix: &str,
    device: &Device,
) -> Result<Vec<PathBuf>> {
    let render = config.render_settings()?;
    let frames = render_views(&render.with(field), cameras, config.image_size(), device)?;
    let mut written = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let p = out_dir.join(format!("{prefix}_{i}.png"));
        write_png(&p, &f.color)?;
        written.push(p);
    }
    Ok(written)
}

/// The parameters of `v` as JSON: the shape's, α, β, the colour.
fn volume_json(v: &SdfVolume) -> serde_json::Value {
    let mut j = match v.sdf {
        Sdf::Box {
            center,
            side_lengths,
        } => json!({"shape": "box", "center": center, "side_lengths": side_lengths}),
        Sdf::Sphere { center, radius } => {
            json!({"shape": "sphere", "center": center, "radius": radius})
        }
    };
    j["alpha"] = json!(v.alpha);
    j["beta"] = json!(v.beta);
    j["feature"] = json!(v.feature);
    j
}

/// The fit's record: initial and fitted parameters, what was trained, steps, losses, time.
pub fn outcome_json(o: &SdfFitOutcome) -> serde_json::Value {
    json!({
        "fitted": volume_json(&o.fitted),
        "initial": volume_json(&o.initial),
        "trained": o.trained,
        "steps": o.report.steps,
        "final_loss": o.report.final_loss,
        "last_epoch_loss": o.report.last_epoch_loss,
        "seconds": o.report.seconds,
    })
}

/// Runs the `train` job of `config` (see the module documentation), writing into `out_dir`.
pub fn train_sdf(config: &Config, out_dir: &Path, device: &Device) -> Result<SdfFitOutcome> {
    let settings = config.sdf_fit_settings()?;
    let initial = config.sdf_volume()?;
    let model = config.sdf_model(device)?;
    if model.varmap().all_vars().is_empty() {
        bail!("implicit_function: no parameter has `opt: True`, so there is nothing to train");
    }
    let views = load_training_views(config)?;
    let cameras: Vec<PerspectiveCamera> = views.iter().map(|v| v.camera).collect();
    prepare_out_dir(out_dir)?;
    let mut written = write_views(
        config,
        &*model.render_field(),
        &cameras,
        out_dir,
        "render_box_before_training",
        device,
    )?;
    let report = fit_sdf(&model, &views, &settings, device, |_, _, _| {})?;
    let fitted = model.render_field();
    written.extend(write_views(
        config,
        &*fitted,
        &cameras,
        out_dir,
        "render_box_after_training",
        device,
    )?);
    let (sampler, renderer) = (config.sampler()?, config.renderer()?);
    let frames = render_views(
        &Pipeline::new(&*fitted, &*sampler, &renderer),
        &config.surround_cameras(),
        config.image_size(),
        device,
    )?;
    let gif = out_dir.join("render_box.gif");
    write_gif(
        &gif,
        &frames.iter().map(|f| f.color.clone()).collect::<Vec<_>>(),
        10,
    )?;
    written.push(gif);
    let mut outcome = SdfFitOutcome {
        initial,
        fitted: model.field.values()?,
        trained: model
            .field
            .variables
            .iter()
            .map(|(n, _)| n.clone())
            .collect(),
        report,
        written,
    };
    let json_path = out_dir.join("sdf_fit.json");
    write_text(
        &json_path,
        &serde_json::to_string_pretty(&outcome_json(&outcome))?,
    )?;
    outcome.written.push(json_path);
    Ok(outcome)
}

/// `nerf targets`: renders each `data.cameras` camera's view of the config's SDF volume and
/// writes it to the camera's `image` path as a float32 `(H, W, 3)` `.npy` (creating its
/// folder), the targets a `type: train` config fits. Every camera must name an image.
pub fn write_targets(config: &Config, device: &Device) -> Result<Vec<PathBuf>> {
    let cameras = config.data_cameras()?;
    let mut paths = Vec::with_capacity(cameras.len());
    for (name, _, image) in &cameras {
        paths.push(image.clone().with_context(|| {
            format!("data.cameras.{name}.image: missing (where to write this camera's target)")
        })?);
    }
    let field = config.sdf_field(device)?;
    let (w, h) = config.image_size();
    let views: Vec<PerspectiveCamera> = cameras.iter().map(|(_, c, _)| *c).collect();
    let render = config.render_settings()?;
    let frames = render_views(&render.with(&field), &views, (w, h), device)?;
    for (path, frame) in paths.iter().zip(&frames) {
        if let Some(dir) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            prepare_out_dir(dir)?;
        }
        write_npy(path, &[h as u64, w as u64, 3], &frame.color.data)?;
    }
    Ok(paths)
}
