//! `nerf train`: a config's NeRF training run, with test-PSNR logging and preview GIFs as the
//! loop's hooks.

use std::path::Path;

use anyhow::Result;
use candle_core::Device;

use crate::app::config::Config;
use crate::app::scene::render_nerf_gif;
use crate::eval::evaluate::evaluate;
use crate::io::checkpoint::CheckpointInfo;
use crate::io::dataset::{Dataset, Split};
use crate::train::fit::{fit, CheckpointScore, Hooks, TrainPaths};

/// Runs `nerf train` for `config` on the dataset in `data_dir`. `stop_after_epochs` ends the
/// run early (after writing a checkpoint) once that many epochs have been done in this process.
pub fn train_nerf(
    config: &Config,
    data_dir: &Path,
    paths: &TrainPaths,
    stop_after_epochs: Option<usize>,
    device: &Device,
) -> Result<CheckpointInfo> {
    let settings = config.train_settings()?;
    let (w, h) = config.image_size();
    let white = config.renderer.white_background;
    let dataset = Dataset::load(data_dir, Split::Train, w, h, white)?;
    let eval_views = config.training()?.eval_views;
    let test = if eval_views > 0 {
        match Dataset::load(data_dir, Split::Test, w, h, white) {
            Ok(d) => Some(d),
            Err(e) => {
                eprintln!("warning: no test-PSNR logging: {e:#}");
                None
            }
        }
    } else {
        None
    };
    let (sampler, renderer) = (config.sampler()?, config.renderer()?);
    let mut hooks = Hooks::default();
    if let Some(test) = &test {
        hooks.evaluate = Some(Box::new(move |field| {
            let report = evaluate(
                field,
                &sampler,
                &renderer,
                test,
                Split::Test,
                None,
                Some(eval_views),
                device,
            )?;
            Ok(CheckpointScore {
                psnr: report.mean_psnr,
                views: report.views.len(),
            })
        }));
    }
    let gif = paths.images.join("render_nerf_training.gif");
    hooks.preview = Some(Box::new(move |field| {
        render_nerf_gif(config, field, &gif, device)
    }));
    fit(&settings, &dataset, paths, stop_after_epochs, hooks, device)
}
