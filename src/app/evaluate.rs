//! `nerf eval`: a config's trained NeRF scored against a dataset split.

use std::path::Path;

use anyhow::Result;
use candle_core::Device;

use crate::app::config::Config;
use crate::eval::evaluate::{evaluate, EvalReport};
use crate::io::dataset::{Dataset, Split};

/// Loads the checkpoint (the one [`Config::checkpoint`] picks for `checkpoint`) and the split at the config's image size and scores every view (the
/// first `limit` with a limit); with `save_images`, writes each prediction there.
pub fn eval_nerf(
    config: &Config,
    checkpoint: Option<&Path>,
    data_dir: &Path,
    split: Split,
    save_images: Option<&Path>,
    limit: Option<usize>,
    device: &Device,
) -> Result<EvalReport> {
    if config.implicit_function.is_sdf_volume() {
        anyhow::bail!(
            "implicit_function.type sdf_volume: this command needs a NeRF config (e.g. lego); eval scores a trained field against a dataset"
        );
    }
    let (w, h) = config.data.dataset_image_size(data_dir)?;
    let dataset = Dataset::load_first(
        data_dir,
        split,
        w,
        h,
        config.renderer.white_background,
        limit,
    )?;
    let field = config.load_field(&config.checkpoint(checkpoint), device)?;
    evaluate(
        &config.render_settings()?.with(&*field),
        &dataset,
        split,
        save_images,
        limit,
        device,
    )
}
