//! `nerf eval`: a config's trained NeRF scored against a dataset split.

use std::path::Path;

use anyhow::Result;
use candle_core::Device;

use crate::app::config::Config;
use crate::eval::evaluate::{evaluate, EvalReport};
use crate::io::checkpoint::ensure_checkpoint_file;
use crate::io::dataset::{Dataset, Split};

/// Loads the checkpoint and the split at the config's image size and scores every view (the
/// first `limit` with a limit); with `save_images`, writes each prediction there.
pub fn eval_nerf(
    config: &Config,
    checkpoint: &Path,
    data_dir: &Path,
    split: Split,
    save_images: Option<&Path>,
    limit: Option<usize>,
    device: &Device,
) -> Result<EvalReport> {
    ensure_checkpoint_file(checkpoint)?;
    let (w, h) = config.image_size();
    let dataset = Dataset::load(data_dir, split, w, h, config.renderer.white_background)?;
    let (state, _) = config.load_nerf(checkpoint, device)?;
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
