//! `nerf eval`: a config's trained NeRF scored against a dataset split.

use std::path::Path;

use anyhow::Result;
use candle_core::Device;

use crate::app::config::Config;
use crate::eval::evaluate::{evaluate, EvalReport};
use crate::io::dataset::{Dataset, Split};

/// Loads the checkpoint ([`Config::nerf_checkpoint`] of `checkpoint`, the `--checkpoint`
/// option) and the split at the config's image size and scores every view (the first `limit`
/// with a limit); with `save_images`, writes each prediction there.
pub fn eval_nerf(
    config: &Config,
    checkpoint: Option<&Path>,
    data_dir: &Path,
    split: Split,
    save_images: Option<&Path>,
    limit: Option<usize>,
    device: &Device,
) -> Result<EvalReport> {
    config.nerf_params()?;
    let checkpoint = config.nerf_checkpoint(checkpoint)?;
    let (w, h) = config.image_size();
    let dataset = Dataset::load(data_dir, split, w, h, config.renderer.white_background)?;
    let (state, _) = config.load_nerf(&checkpoint, device)?;
    evaluate(
        &state.field(),
        &config.sampler()?,
        &config.renderer()?,
        &dataset,
        split,
        save_images,
        limit,
        device,
    )
}
