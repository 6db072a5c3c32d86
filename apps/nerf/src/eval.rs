//! `nerf eval`: a config's trained NeRF scored against a dataset split.

use std::path::Path;

use anyhow::Result;
use candle_core::Device;

use crate::render::scene_frame::{note_scene_frame, stored_transform};
use nerf::config::{Config, SizeUse};
use nerf::eval::evaluate::{evaluate, EvalReport};
use nerf::eval::protocol::protocol_line;
use nerf::io::dataset::{Dataset, Split};

/// Loads the checkpoint (the one [`Config::checkpoint`] picks for `checkpoint`) and the split
/// at the config's image size, a capture in the frame the checkpoint stores, and scores every
/// view (the first `limit` with a limit); with `save_images`, writes each prediction there.
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
    let size = config.data.dataset_image_size(data_dir, SizeUse::Scoring)?;
    let path = config.checkpoint(checkpoint);
    let stored = stored_transform(&path)?;
    let dataset = Dataset::load_first_with(
        data_dir,
        split,
        size,
        config.renderer.white_background,
        limit,
        stored,
    )?;
    note_scene_frame(data_dir, &path, stored, dataset.normalisation.as_ref());
    let (model, _) = config.load_model(&path, device)?;
    if let Some(info) = &dataset.capture {
        let appearance = model
            .field
            .parameter_shapes()
            .iter()
            .any(|(name, _)| name == nerf::field::appearance::EMBEDDING);
        let size = (dataset.width, dataset.height);
        let frames = dataset.frames.len();
        let line = protocol_line(info, split, frames, size, appearance);
        nerf::core::term::note(&line);
    }
    let field = model.render_field();
    evaluate(
        &config.render_settings()?.with(&*field),
        &dataset,
        split,
        save_images,
        limit,
        device,
    )
}
