//! Configuration in the homework's YAML schema, with Hydra-style `key.sub=value` overrides.
//!
//! A homework config file works unmodified. Unknown keys, wrong types and bad values are
//! errors that name the key. Extensions beyond the homework (all optional):
//! `cameras` (the surround views to render) and `data.data_dir` (where the dataset lives).

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Result};
use serde::de::DeserializeOwned;
use serde::Deserialize;
use serde_yaml_ng::{Mapping, Value};

use crate::app::yaml_bounds::{self, MAX_YAML_BYTES};

/// Upper limits on sizes, so that a typo such as an extra zero is a one-line error naming the
/// key instead of an allocation that exhausts memory. Each is far above what the homework's
/// scenes use (400×400 images, 128 samples per ray, 1024-ray batches, 20 poses).
pub mod limits {
    /// Largest image width or height.
    pub const IMAGE_SIDE: usize = 4096;
    /// Most samples per ray.
    pub const PTS_PER_RAY: usize = 16384;
    /// Most surround poses.
    pub const POSES: usize = 3600;
    /// Most pixels over all surround frames (every frame is kept in memory for the GIF).
    pub const FRAME_PIXELS: usize = 1 << 26;
    /// Most samples in one training batch (`batch_size × n_pts_per_ray`), all held with
    /// their activations for the backward pass.
    pub const BATCH_SAMPLES: usize = 1 << 21;
    /// Most samples drawn in one step whose rays adapt to `training.samples_per_step`: with an
    /// occupancy grid or early termination only the evaluated ones hold activations, a drawn
    /// one costs its depth and a grid test.
    pub const DRAWN_SAMPLES: usize = 1 << 23;
    /// Most harmonic functions of a positional embedding (2^31 is past f32 precision).
    pub const HARMONICS: usize = 32;
    /// Widest hidden layer.
    pub const HIDDEN: usize = 4096;
    /// Deepest trunk.
    pub const LAYERS: usize = 64;
    /// Most marching-cubes cells per side of `nerf export mesh`: 513³ density samples, 0.5 GiB
    /// held as one grid (the field is evaluated into it [`GRID_BATCH`] points at a time, and
    /// the mesher reads it in place, welding each cube's triangles as it goes).
    pub const MESH_RESOLUTION: usize = 512;
    /// Most triangles of a mesh (about 1 GiB for the mesh, its welding table and its colours
    /// at this size); a field noisy enough to need more is refused before the PLY is written,
    /// asking for a higher threshold or a lower resolution.
    pub const MESH_FACES: usize = 1 << 24;
    /// Most rays (views × pixels) of `nerf export points`, checked before anything is rendered:
    /// the cloud is held until it is written, 24 bytes a point (at most 3 GiB).
    pub const POINT_CLOUD_RAYS: usize = 1 << 27;

    // Working memory. Whatever the sizes above, every job works through its images, sample
    // sets and grids in pieces whose intermediate tensors stay within about 1 GiB, so that
    // what a job holds at once is its outputs (the frames, the grid, the mesh) plus that:
    // * the renderer evaluates at most `Field::max_samples_per_chunk` samples at once (an SDF
    //   2^22, about 250 MB; a NeRF 2^15; a hash grid 2^16), and, when it skips samples, draws
    //   at most [`DRAWN_SAMPLES_PER_CHUNK`];
    // * an image's rays are made, rendered and turned into pixels [`BAND_RAYS`] at a time (the
    //   vis images, the depth points and the mesh's colour rays too);
    // * `point_vis`'s sample points are made and splatted [`POINT_SAMPLES`] at a time;
    // * a mesh grid is evaluated [`GRID_BATCH`] points at a time.
    // The environment variable `NERF_WORK_CHUNK=N` lowers every one of these pieces to N items
    // (rays, points) for tests of chunking; the outputs do not depend on it. Measured at the
    // largest sizes: a 4096² box render peaks at 1.7 GB resident (its frame, three vis images
    // and the bands), `export mesh --resolution 512` of the box at 0.7 GB.

    /// Rays per band of an image (rounded to whole renderer chunks where rendered): 2^18 rays
    /// are about 60 MB of rays, pixels and outputs, on top of the renderer's chunk.
    pub const BAND_RAYS: usize = crate::render::bands::BAND_RAYS;
    /// Sample points of `point_vis` made and splatted at once (2^22: about 100 MB).
    pub const POINT_SAMPLES: usize = 1 << 22;
    /// Grid points of a mesh grid evaluated at once.
    pub const GRID_BATCH: usize = 1 << 16;
    /// Most samples drawn per renderer chunk when samples are skipped (an occupancy grid or
    /// early termination): each costs its depth and march state, and all of a chunk's may be
    /// evaluated when nothing terminates.
    pub const DRAWN_SAMPLES_PER_CHUNK: usize = crate::render::renderer::DRAWN_SAMPLES_PER_CHUNK;
}

/// An error naming `key` when `v` is not in `1..=max`.
fn count_in_range(key: &str, v: usize, max: usize) -> Result<()> {
    if v == 0 || v > max {
        bail!("{key}: must be 1 to {max} (got {v})");
    }
    Ok(())
}

/// Says where a bad value came from: the first override whose addition makes the config fail
/// (`override `key=value`: …`), or else the file, with the line of the offending key when it
/// can be found (`config FILE, line N: …`).
fn blame(text: &str, origin: &str, overrides: &[String], error: anyhow::Error) -> anyhow::Error {
    if format!("{error:#}").starts_with("override `") {
        // An override that could not be applied names itself already.
        return error;
    }
    if Config::from_yaml(text, &[]).is_ok() {
        for n in 1..=overrides.len() {
            if Config::from_yaml(text, &overrides[..n]).is_err() {
                return error.context(format!("override `{}`", quoted(&overrides[n - 1])));
            }
        }
    }
    let message = format!("{error:#}");
    let key = message.split(':').next().unwrap_or("");
    match key_line(text, key) {
        Some(line) => error.context(format!("config {origin}, line {line}")),
        None => error.context(format!("config {origin}")),
    }
}

/// The 1-based line of `key` (dotted, e.g. `sampler.n_pts_per_ray`) in YAML `text`: each part
/// found in order, deeper than the one before. `None` when some part is not found.
fn key_line(text: &str, key: &str) -> Option<usize> {
    let lines: Vec<&str> = text.lines().collect();
    let (mut from, mut indent, mut found) = (0usize, -1i64, None);
    for part in key.split('.').map(|p| p.split('[').next().unwrap_or(p)) {
        let hit = (from..lines.len()).find(|&i| {
            let l = lines[i];
            let depth = (l.len() - l.trim_start().len()) as i64;
            depth > indent && l.trim_start().starts_with(&format!("{part}:"))
        })?;
        indent = (lines[hit].len() - lines[hit].trim_start().len()) as i64;
        from = hit + 1;
        found = Some(hit + 1);
    }
    found
}

/// Configs shipped with the binary, found by name when `configs/NAME.yaml` is not on disk.
const BUILT_IN: &[(&str, &str)] = &[
    ("box", include_str!("../../configs/box.yaml")),
    ("sphere", include_str!("../../configs/sphere.yaml")),
    ("lego", include_str!("../../configs/lego.yaml")),
    ("nerf_lego", include_str!("../../configs/nerf_lego.yaml")),
    (
        "nerf_lego_fast",
        include_str!("../../configs/nerf_lego_fast.yaml"),
    ),
    (
        "nerf_lego_highres",
        include_str!("../../configs/nerf_lego_highres.yaml"),
    ),
    (
        "nerf_lego_render",
        include_str!("../../configs/nerf_lego_render.yaml"),
    ),
    ("train_box", include_str!("../../configs/train_box.yaml")),
    (
        "nerf_lego_ngp",
        include_str!("../../configs/nerf_lego_ngp.yaml"),
    ),
    ("lego_ngp", include_str!("../../configs/lego_ngp.yaml")),
    (
        "nerf_lego_ngp_400",
        include_str!("../../configs/nerf_lego_ngp_400.yaml"),
    ),
    (
        "lego_ngp_400",
        include_str!("../../configs/lego_ngp_400.yaml"),
    ),
];

/// A homework parameter `{val, opt}`; `opt` marks it trainable in the homework.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Param<T> {
    /// The value.
    pub val: T,
    /// Trainable in the homework (`opt: True`); default false.
    #[serde(default)]
    pub opt: bool,
}

/// The `data` section.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    /// `[width, height]` in pixels.
    pub image_size: [usize; 2],
    /// `data.dataset_name`, e.g. `lego`: names the default data directory and the checkpoint file.
    #[serde(default)]
    pub dataset_name: Option<String>,
    /// Directory holding the dataset (extension; default `../shared/data/<dataset_name>`).
    #[serde(default)]
    pub data_dir: Option<PathBuf>,
    /// `data.cameras`: the training cameras of an SDF fit (`type: train`), in order.
    #[serde(default)]
    pub cameras: Option<DataCameras>,
}

/// The `renderer` section (the homework's keys plus the acceleration extensions).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RendererConfig {
    /// `renderer.type`: only `volume` (the default).
    #[serde(rename = "type", default)]
    pub kind: RendererKind,
    /// Rays rendered per chunk (`renderer.chunk_size`, at least 1).
    pub chunk_size: usize,
    /// Composite onto white instead of black (`renderer.white_background`, default false).
    #[serde(default)]
    pub white_background: bool,
    /// Extension: stop marching a ray once its transmittance falls below this (0 = off, the
    /// homework's dense rendering). Needs a NeRF field.
    #[serde(default)]
    pub early_termination: f64,
    /// Extension: skip samples in empty cells of an occupancy grid (NeRF fields).
    #[serde(default)]
    pub occupancy_grid: Option<OccupancyGridConfig>,
}

/// `renderer.type`: the homework's one renderer.
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum RendererKind {
    /// `volume`: the homework's `VolumeRenderer`.
    #[default]
    Volume,
}

/// `sampler.type`: the homework's one sampler.
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SamplerKind {
    /// `stratified`: the homework's `StratifiedRaysampler`.
    #[default]
    Stratified,
}

/// `implicit_function.sdf.type`.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum SdfKind {
    /// `box`: an axis-aligned box with `side_lengths`.
    Box,
    /// `sphere`: a sphere with `radius`.
    Sphere,
}

/// `renderer.occupancy_grid` (extension): the empty-space skipping grid, and how training
/// keeps it up to date (nerfacc's defaults).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct OccupancyGridConfig {
    /// Cells per side.
    #[serde(default = "d64")]
    pub resolution: usize,
    /// `[min_x, min_y, min_z, max_x, max_y, max_z]`; outside it the field is taken as empty.
    #[serde(default = "default_aabb")]
    pub aabb: [f64; 6],
    /// A cell is occupied while one sample step through it would have at least this opacity.
    #[serde(default = "default_alpha_threshold")]
    pub alpha_threshold: f64,
    /// Training: update the grid every this many steps.
    #[serde(default = "d16")]
    pub update_interval: usize,
    /// Training: probe every cell at each update for the first this many steps.
    #[serde(default = "d256")]
    pub warmup_steps: usize,
    /// Training: decay of each cell's running density maximum per update.
    #[serde(default = "default_decay")]
    pub decay: f64,
}

impl Default for OccupancyGridConfig {
    fn default() -> Self {
        Self {
            resolution: d64(),
            aabb: default_aabb(),
            alpha_threshold: default_alpha_threshold(),
            update_interval: d16(),
            warmup_steps: d256(),
            decay: default_decay(),
        }
    }
}

fn default_aabb() -> [f64; 6] {
    [-1.5, -1.5, -1.5, 1.5, 1.5, 1.5]
}
fn default_alpha_threshold() -> f64 {
    0.01
}
fn default_decay() -> f64 {
    0.95
}
fn d16() -> usize {
    16
}
fn d256() -> usize {
    256
}

/// The `sampler` section.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SamplerConfig {
    /// `sampler.type`: only `stratified` (the default).
    #[serde(rename = "type", default)]
    pub kind: SamplerKind,
    /// Samples per ray (`sampler.n_pts_per_ray`, 1 to [`limits::PTS_PER_RAY`]).
    pub n_pts_per_ray: usize,
    /// Depth of the first sample along each ray, in world units (`sampler.min_depth`, ≥ 0).
    pub min_depth: f64,
    /// Depth of the last sample along each ray (`sampler.max_depth`, ≥ `min_depth`).
    pub max_depth: f64,
    /// Coarse-to-fine sampling (`sampler.n_pts_per_ray_fine`, default 0 = off): this many
    /// more depths per ray drawn from the weights of a coarse pass over the `n_pts_per_ray`
    /// stratified ones ([`crate::render::hierarchical`]); not with an occupancy grid or early
    /// termination.
    #[serde(default)]
    pub n_pts_per_ray_fine: usize,
}

/// `implicit_function.sdf`: the shape (`box` with `side_lengths`, or `sphere` with `radius`).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SdfShapeConfig {
    /// `implicit_function.sdf.type`: `box` or `sphere`.
    #[serde(rename = "type")]
    pub kind: SdfKind,
    /// `implicit_function.sdf.center`: the shape's centre `[x, y, z]` in world units.
    pub center: Param<[f64; 3]>,
    /// `implicit_function.sdf.side_lengths`: the box's full side lengths (required for a box).
    #[serde(default)]
    pub side_lengths: Option<Param<[f64; 3]>>,
    /// `implicit_function.sdf.radius`: the sphere's radius (required for a sphere).
    #[serde(default)]
    pub radius: Option<Param<f64>>,
}

/// `implicit_function.feature`: a constant colour, or the homework's rainbow colouring.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FeatureConfig {
    /// `implicit_function.feature.rainbow`: colour `clamp(|p − center|, 0.02, 0.98) · val`
    /// instead of the constant `val` (default false).
    #[serde(default)]
    pub rainbow: bool,
    /// `implicit_function.feature.val`: the RGB colour (the rainbow colouring's scale).
    pub val: [f64; 3],
    /// `implicit_function.feature.opt`: train the colour (default false).
    #[serde(default)]
    pub opt: bool,
}

/// `implicit_function` with `type: sdf_volume`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SdfVolumeConfig {
    /// `implicit_function.type`: `sdf_volume`.
    #[serde(rename = "type")]
    pub kind: String,
    /// `implicit_function.sdf`: the shape.
    pub sdf: SdfShapeConfig,
    /// `implicit_function.feature`: the colour.
    pub feature: FeatureConfig,
    /// `implicit_function.alpha`: the density scale α of the SDF → density map, in [0, 1].
    pub alpha: Param<f64>,
    /// `implicit_function.beta`: the SDF → density falloff β in world units (> 0).
    pub beta: Param<f64>,
}

/// `implicit_function` with `type: nerf` (the homework's keys and defaults).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NerfConfig {
    /// `implicit_function.type`: `nerf`.
    #[serde(rename = "type")]
    pub kind: String,
    /// Harmonic frequencies of the point embedding (`n_harmonic_functions_xyz`, default 6).
    #[serde(default = "d6")]
    pub n_harmonic_functions_xyz: usize,
    /// Harmonic frequencies of the direction embedding (`n_harmonic_functions_dir`, default 2).
    #[serde(default = "d2")]
    pub n_harmonic_functions_dir: usize,
    /// Width of the `mlp_xyz` trunk layers (`n_hidden_neurons_xyz`, default 128).
    #[serde(default = "d128")]
    pub n_hidden_neurons_xyz: usize,
    /// Width of the colour head's hidden layer (`n_hidden_neurons_dir`, default 64).
    #[serde(default = "d64")]
    pub n_hidden_neurons_dir: usize,
    /// Std of the Gaussian noise added to the raw density in training (`density_noise_std`,
    /// default 0).
    #[serde(default)]
    pub density_noise_std: f64,
    /// Layers of the `mlp_xyz` trunk (`n_layers_xyz`, default 6).
    #[serde(default = "d6")]
    pub n_layers_xyz: usize,
    /// Trunk layers before which the point embedding is concatenated again (`append_xyz`,
    /// default `[3]`).
    #[serde(default = "default_append_xyz")]
    pub append_xyz: Vec<usize>,
}

/// `implicit_function` with `type: ngp`: the hash-grid field ([`crate::field::ngp`]).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NgpConfig {
    /// `implicit_function.type`: `ngp`.
    #[serde(rename = "type")]
    pub kind: String,
    /// Levels of the hash grid `L` (`n_levels`, default 16).
    #[serde(default = "d16")]
    pub n_levels: usize,
    /// Features per level `F` (`n_features_per_level`, default 2).
    #[serde(default = "d2")]
    pub n_features_per_level: usize,
    /// `log2` of the rows of each level's table `T` (`log2_hashmap_size`, default 19).
    #[serde(default = "d19")]
    pub log2_hashmap_size: u32,
    /// Coarsest grid resolution `N_min` (`base_resolution`, default 16).
    #[serde(default = "d16f")]
    pub base_resolution: f64,
    /// Finest grid resolution `N_max` (`max_resolution`; default 2048 × the box's half-size,
    /// the largest over the axes: 3072 for the default box).
    #[serde(default)]
    pub max_resolution: Option<f64>,
    /// The box the grid covers, `[[min x, y, z], [max x, y, z]]` in world units (`aabb`,
    /// default ±1.5 on every axis: the lego scene and its occupancy grid).
    #[serde(default = "default_ngp_aabb")]
    pub aabb: [[f64; 3]; 2],
    /// `trunc_exp` (default, instant-ngp) or `softplus` (`density_activation`).
    #[serde(default = "default_density_activation")]
    pub density_activation: String,
}

impl NgpConfig {
    /// The field's sizes (an error for an unknown density activation or a bad grid or box).
    pub fn params(&self) -> Result<crate::field::ngp::NgpParams> {
        use crate::field::ngp::{DensityActivation, NgpParams};
        let density_activation = match self.density_activation.as_str() {
            "trunc_exp" => DensityActivation::TruncExp,
            "softplus" => DensityActivation::Softplus,
            other => bail!(
                "implicit_function.density_activation: unknown `{other}` (expected trunc_exp or softplus)"
            ),
        };
        let half = (0..3)
            .map(|a| (self.aabb[1][a] - self.aabb[0][a]) / 2.0)
            .fold(0.0, f64::max);
        let params = NgpParams {
            grid: crate::kernels::hash_grid::HashGridParams {
                n_levels: self.n_levels,
                n_features: self.n_features_per_level,
                log2_table_size: self.log2_hashmap_size,
                base_resolution: self.base_resolution,
                max_resolution: self.max_resolution.unwrap_or(2048.0 * half),
            },
            aabb: self.aabb,
            density_activation,
        };
        params.validate()?;
        Ok(params)
    }
}

fn d16f() -> f64 {
    16.0
}
fn d19() -> u32 {
    19
}
fn default_ngp_aabb() -> [[f64; 3]; 2] {
    [[-1.5; 3], [1.5; 3]]
}
fn default_density_activation() -> String {
    "trunc_exp".into()
}
fn d2() -> usize {
    2
}
fn d6() -> usize {
    6
}
fn d64() -> usize {
    64
}
fn d128() -> usize {
    128
}
fn default_append_xyz() -> Vec<usize> {
    vec![3]
}

/// The typed `implicit_function` section.
#[derive(Debug, Clone, PartialEq)]
pub enum ImplicitFunctionConfig {
    /// `type: sdf_volume`: an analytic SDF volume.
    SdfVolume(SdfVolumeConfig),
    /// `type: nerf`: the homework's NeRF.
    Nerf(NerfConfig),
    /// `type: ngp`: the hash-grid field.
    Ngp(NgpConfig),
}

/// `training`, as written: every key may be missing, since each job reads only its own
/// (`train_nerf` all of the homework's, `train` the first three, `render_nerf` only the
/// checkpoint). A job asks for a key with [`TrainingConfig::required`], which names a missing
/// one. The homework's code has no defaults for these keys.
#[derive(Debug, Clone, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TrainingConfig {
    /// Epochs to train (`training.num_epochs`): one step per training image (NeRF) or per
    /// training camera (the box fit) each.
    #[serde(default)]
    pub num_epochs: Option<usize>,
    /// Rays per training step (`training.batch_size`).
    #[serde(default)]
    pub batch_size: Option<usize>,
    /// Initial Adam learning rate (`training.lr`).
    #[serde(default)]
    pub lr: Option<f64>,
    /// Epochs between learning-rate decays (`training.lr_scheduler_step_size`).
    #[serde(default)]
    pub lr_scheduler_step_size: Option<usize>,
    /// Learning-rate factor per `lr_scheduler_step_size` epochs (`training.lr_scheduler_gamma`).
    #[serde(default)]
    pub lr_scheduler_gamma: Option<f64>,
    /// The checkpoint (`training.checkpoint_path`): a checkpoint file (ours or a PyTorch
    /// one), or a directory holding `nerf_<dataset_name>.safetensors` (see
    /// `crate::app::checkpoints`). An empty string means none, as in the homework.
    #[serde(default)]
    pub checkpoint_path: Option<PathBuf>,
    /// Epochs between checkpoints (`training.checkpoint_interval`).
    #[serde(default)]
    pub checkpoint_interval: Option<usize>,
    /// Continue from the checkpoint when one exists (`training.resume`, default false).
    #[serde(default)]
    pub resume: bool,
    /// Epochs between preview renders (`training.render_interval`).
    #[serde(default)]
    pub render_interval: Option<usize>,
    /// Extension: draw each batch's rays from all training images instead of one image per
    /// step (the homework's scheme, the default).
    #[serde(default)]
    pub rays_from_all_images: bool,
    /// Extension: composite each training ray onto a random colour (prediction and target
    /// alike) instead of the fixed background, so that density where the object is
    /// transparent costs loss even when its colour matches the background.
    #[serde(default)]
    pub random_background: bool,
    /// Extension: at every checkpoint, log the test PSNR over the first this many test views
    /// (0 = off).
    #[serde(default)]
    pub eval_views: usize,
    /// Extension: adapt the rays per step so that each step evaluates about this many samples
    /// (instant-ngp's scheme: many rays once the occupancy grid and early termination leave
    /// few samples per ray); `batch_size` is then the first step's rays. Unset: fixed.
    #[serde(default)]
    pub samples_per_step: Option<usize>,
}

impl TrainingConfig {
    /// The value of `training.<key>`, or an error naming the key and the job that needs it.
    pub fn required<T: Copy>(value: Option<T>, key: &str, job: &str) -> Result<T> {
        value.ok_or_else(|| anyhow!("training.{key}: missing (needed to {job})"))
    }

    /// The checkpoint path, `None` when missing or empty (the homework's "no checkpoint").
    pub fn checkpoint(&self) -> Option<&Path> {
        self.checkpoint_path
            .as_deref()
            .filter(|p| !p.as_os_str().is_empty())
    }
}

/// The homework's top-level `type`: the job `nerf run` (the homework's `main.py`) runs.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum JobKind {
    /// `render`: render a scene (`nerf render`).
    Render,
    /// `render_nerf`: render a trained NeRF from `training.checkpoint_path` (`nerf render`).
    RenderNerf,
    /// `train`: fit an SDF volume's `opt: True` parameters to images (`nerf train`).
    Train,
    /// `train_nerf`: train a NeRF on a dataset (`nerf train`).
    TrainNerf,
}

impl JobKind {
    /// The name as written in a config.
    pub fn name(self) -> &'static str {
        match self {
            JobKind::Render => "render",
            JobKind::RenderNerf => "render_nerf",
            JobKind::Train => "train",
            JobKind::TrainNerf => "train_nerf",
        }
    }

    /// Whether the job renders (rather than trains).
    pub fn renders(self) -> bool {
        matches!(self, JobKind::Render | JobKind::RenderNerf)
    }
}

/// One camera of `data.cameras` (the homework's `train_box.yaml`): pytorch3d's
/// `look_at_view_transform(eye, scene_center, up)` with an NDC focal length and principal
/// point, and the image it sees.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DataCameraConfig {
    /// NDC focal length (both axes).
    pub focal: f64,
    /// Camera position in world units.
    pub eye: [f64; 3],
    /// NDC principal point `(p_x, p_y)`.
    pub principal_point: [f64; 2],
    /// The point the camera looks at.
    pub scene_center: [f64; 3],
    /// Up direction.
    pub up: [f64; 3],
    /// The target image: a `.npy` float array `(H, W, 3)`, relative to the working directory
    /// (needed to train).
    #[serde(default)]
    pub image: Option<PathBuf>,
}

/// `data.cameras`: named cameras in the order written.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DataCameras(pub Vec<(String, DataCameraConfig)>);

impl<'de> Deserialize<'de> for DataCameras {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct Ordered;
        impl<'de> serde::de::Visitor<'de> for Ordered {
            type Value = DataCameras;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a mapping of camera names to cameras")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> std::result::Result<DataCameras, A::Error> {
                let mut cameras = Vec::new();
                while let Some((name, camera)) = map.next_entry::<String, DataCameraConfig>()? {
                    cameras.push((name, camera));
                }
                Ok(DataCameras(cameras))
            }
        }
        d.deserialize_map(Ordered)
    }
}

/// `cameras` (extension): the surround views rendered by `nerf render`.
#[derive(Debug, Clone, PartialEq)]
pub struct CamerasConfig {
    /// Distance of the cameras from the origin (`cameras.radius`; default 3 for SDF, 4 for NeRF).
    pub radius: f64,
    /// Number of views around the scene (`cameras.n_poses`, default 20).
    pub n_poses: usize,
    /// Up vector of the cameras (`cameras.up`; default +Y for SDF, +Z for NeRF).
    pub up: [f64; 3],
    /// NDC focal length of the cameras (`cameras.focal_length`; default 1 for SDF, 2 for NeRF).
    pub focal_length: f64,
}

/// `cameras` as written: any key left out takes the scene type's default.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamerasConfig {
    radius: Option<f64>,
    n_poses: Option<usize>,
    up: Option<[f64; 3]>,
    focal_length: Option<f64>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    #[serde(default)]
    seed: Option<u64>,
    #[serde(rename = "type", default)]
    kind: Option<JobKind>,
    data: DataConfig,
    renderer: RendererConfig,
    sampler: SamplerConfig,
    implicit_function: Value,
    #[serde(default)]
    training: Option<TrainingConfig>,
    #[serde(default)]
    cameras: Option<RawCamerasConfig>,
}

/// A fully parsed and validated configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Random seed (top-level `seed`, default 0).
    pub seed: u64,
    /// The homework's top-level `type`: the job `nerf run` runs (`nerf render` and
    /// `nerf train` check it).
    pub kind: Option<JobKind>,
    /// The `data` section.
    pub data: DataConfig,
    /// The `renderer` section.
    pub renderer: RendererConfig,
    /// The `sampler` section.
    pub sampler: SamplerConfig,
    /// The `implicit_function` section, typed by its `type`.
    pub implicit_function: ImplicitFunctionConfig,
    /// The `training` section, when present (needed to train).
    pub training: Option<TrainingConfig>,
    /// The `cameras` section, any key left out taking the scene type's default.
    pub cameras: CamerasConfig,
}

/// Deserialises `value` into `T`, prefixing errors with the dotted key path.
fn from_value<T: DeserializeOwned>(value: Value, prefix: &str) -> Result<T> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let path = e.path().to_string();
        let key = match (prefix.is_empty(), path == ".") {
            (true, true) => "config".to_string(),
            (true, false) => path,
            (false, true) => prefix.to_string(),
            (false, false) => format!("{prefix}.{path}"),
        };
        anyhow!(
            "{}: {}",
            one_line(&key),
            one_line(&in_user_words(&e.into_inner().to_string()))
        )
    })
}

/// A deserialiser message with Rust type names replaced by what a config writer knows:
/// "expected usize" → "expected a whole number", "expected struct SamplerConfig" → "expected a
/// section of `key: value` lines", and so on.
pub fn in_user_words(message: &str) -> String {
    let mut m = message.to_string();
    for (rust, words) in [
        ("usize", "a whole number"),
        ("u64", "a whole number"),
        ("u32", "a whole number"),
        ("f64", "a number"),
        ("f32", "a number"),
        ("a sequence", "a list"),
    ] {
        m = m.replace(&format!("expected {rust}"), &format!("expected {words}"));
    }
    if let Some(i) = m.find("expected struct ") {
        let end = m[i + 16..]
            .find(|c: char| !c.is_alphanumeric() && c != '_')
            .map_or(m.len(), |j| i + 16 + j);
        m.replace_range(i..end, "expected a section of `key: value` lines");
    }
    if let Some(i) = m.find("expected an array of length ") {
        let rest = &m[i + 28..];
        let n: String = rest.chars().take_while(char::is_ascii_digit).collect();
        let end = i + 28 + n.len();
        m.replace_range(i..end, &format!("expected a list of {n} values"));
    }
    m
}

/// `s` with its control characters escaped, so that a message quoting it stays on one line.
fn one_line(s: &str) -> String {
    s.chars()
        .flat_map(|c| {
            let escaped: Vec<char> = if c.is_control() {
                c.escape_default().collect()
            } else {
                vec![c]
            };
            escaped
        })
        .collect()
}

/// `s` for quoting in a message: on one line ([`one_line`]) and cut to its first 100
/// characters (an override can be as long as the command line).
fn quoted(s: &str) -> String {
    let mut out = one_line(s);
    if let Some((i, _)) = out.char_indices().nth(100) {
        out.truncate(i);
        out.push('…');
    }
    out
}

/// Applies one `key.sub=value` override; the value is parsed as YAML. An error is one line
/// that starts with ``override `key=value`:`` and says what is wrong with it.
pub fn apply_override(root: &mut Value, assignment: &str) -> Result<()> {
    apply_override_inner(root, assignment)
        .map_err(|e| anyhow!("override `{}`: {e:#}", quoted(assignment)))
}

fn apply_override_inner(root: &mut Value, assignment: &str) -> Result<()> {
    let (key, raw) = assignment
        .split_once('=')
        .ok_or_else(|| anyhow!("not of the form key.sub=value"))?;
    // Hydra's `+key=value` (add a key) and `++key=value` (add or override): keys are added
    // as needed here anyway, so the prefix is accepted and dropped.
    let key = key.trim().trim_start_matches('+');
    if key.is_empty() || key.split('.').any(str::is_empty) {
        bail!("empty key");
    }
    if key.split('.').count() > yaml_bounds::MAX_YAML_DEPTH {
        bail!(
            "the key has more than {} parts",
            yaml_bounds::MAX_YAML_DEPTH
        );
    }
    yaml_bounds::check_yaml_bounds(raw, "the value")?;
    let value: Value = serde_yaml_ng::from_str(raw)
        .map_err(|e| anyhow!("cannot parse the value: {}", one_line(&e.to_string())))?;
    let parts: Vec<&str> = key.split('.').collect();
    let mut node = root;
    for (i, part) in parts.iter().enumerate() {
        let map = match node {
            Value::Mapping(m) => m,
            Value::Null => {
                *node = Value::Mapping(Mapping::new());
                match node {
                    Value::Mapping(m) => m,
                    _ => unreachable!(),
                }
            }
            _ => bail!("`{}` is not a section", parts[..i].join(".")),
        };
        let k = Value::String((*part).to_string());
        if i + 1 == parts.len() {
            map.insert(k, value);
            return Ok(());
        }
        node = map.entry(k).or_insert(Value::Null);
    }
    Ok(())
}

/// The text of the config file `path`: a regular file of at most [`MAX_YAML_BYTES`], UTF-8.
fn read_config_file(path: &Path) -> Result<String> {
    let bytes = crate::io::bounded_read::read_regular_file(path, "config", MAX_YAML_BYTES as u64)?;
    String::from_utf8(bytes).map_err(|_| anyhow!("config {} is not UTF-8 text", path.display()))
}

/// The YAML text for `--config NAME_OR_PATH`: an existing file path, `configs/NAME.yaml`, or a
/// built-in config of that name.
pub fn config_text(name_or_path: &str) -> Result<(String, String)> {
    let path = Path::new(name_or_path);
    if path.is_file() {
        return Ok((read_config_file(path)?, path.display().to_string()));
    }
    let looks_like_path = name_or_path.contains('/')
        || name_or_path.ends_with(".yaml")
        || name_or_path.ends_with(".yml");
    if looks_like_path && path.is_dir() {
        bail!("config {name_or_path} is a directory, not a YAML file");
    }
    if looks_like_path && path.exists() {
        // A FIFO, a socket or a device: refused before it is opened.
        crate::io::bounded_read::check_regular_file(path, "config", MAX_YAML_BYTES as u64)?;
    }
    if !looks_like_path {
        let local = Path::new("configs").join(format!("{name_or_path}.yaml"));
        if local.is_file() {
            return Ok((read_config_file(&local)?, local.display().to_string()));
        }
        if let Some((_, text)) = BUILT_IN.iter().find(|(n, _)| *n == name_or_path) {
            return Ok(((*text).to_string(), format!("built-in {name_or_path}")));
        }
    }
    if looks_like_path {
        bail!("config file {name_or_path} not found");
    }
    let known: Vec<&str> = BUILT_IN.iter().map(|(n, _)| *n).collect();
    bail!("config `{name_or_path}` not found (not a file, not configs/{name_or_path}.yaml; built-in configs: {})", known.join(", "))
}

impl Config {
    /// Loads `--config NAME_OR_PATH` and applies the overrides in order.
    pub fn load(name_or_path: &str, overrides: &[String]) -> Result<Self> {
        let (text, origin) = config_text(name_or_path)?;
        Self::from_yaml(&text, overrides).map_err(|e| blame(&text, &origin, overrides, e))
    }

    /// Parses YAML text, applies overrides, and validates.
    pub fn from_yaml(text: &str, overrides: &[String]) -> Result<Self> {
        yaml_bounds::check_yaml_bounds(text, "the config")?;
        let mut root: Value = serde_yaml_ng::from_str(text)
            .map_err(|e| anyhow!("malformed YAML: {}", one_line(&e.to_string())))?;
        if !matches!(root, Value::Mapping(_)) {
            bail!("malformed config: the top level must be a mapping of sections");
        }
        for o in overrides {
            apply_override(&mut root, o)?;
        }
        let raw: RawConfig = from_value(root, "")?;
        let kind = raw
            .implicit_function
            .get("type")
            .and_then(Value::as_str)
            .ok_or_else(|| anyhow!("implicit_function.type: missing (sdf_volume, nerf or ngp)"))?
            .to_string();
        let implicit_function = match kind.as_str() {
            "sdf_volume" => ImplicitFunctionConfig::SdfVolume(from_value(
                raw.implicit_function,
                "implicit_function",
            )?),
            "nerf" => ImplicitFunctionConfig::Nerf(from_value(
                raw.implicit_function,
                "implicit_function",
            )?),
            "ngp" => {
                ImplicitFunctionConfig::Ngp(from_value(raw.implicit_function, "implicit_function")?)
            }
            other => bail!(
                "implicit_function.type: unknown type `{other}` (expected sdf_volume, nerf or ngp)"
            ),
        };
        let defaults = default_cameras(&implicit_function);
        let given = raw.cameras.unwrap_or_default();
        let cameras = CamerasConfig {
            radius: given.radius.unwrap_or(defaults.radius),
            n_poses: given.n_poses.unwrap_or(defaults.n_poses),
            up: given.up.unwrap_or(defaults.up),
            focal_length: given.focal_length.unwrap_or(defaults.focal_length),
        };
        let config = Config {
            seed: raw.seed.unwrap_or(0),
            kind: raw.kind,
            data: raw.data,
            renderer: raw.renderer,
            sampler: raw.sampler,
            implicit_function,
            training: raw.training,
            cameras,
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks every value's range, naming the key of the first bad one.
    pub fn validate(&self) -> Result<()> {
        let [w, h] = self.data.image_size;
        if w == 0 || h == 0 || w > limits::IMAGE_SIDE || h > limits::IMAGE_SIDE {
            bail!(
                "data.image_size: width and height must be 1 to {} (got [{w}, {h}])",
                limits::IMAGE_SIDE
            );
        }
        count_in_range(
            "sampler.n_pts_per_ray",
            self.sampler.n_pts_per_ray,
            limits::PTS_PER_RAY,
        )?;
        if self.sampler.n_pts_per_ray_fine > limits::PTS_PER_RAY {
            bail!(
                "sampler.n_pts_per_ray_fine: must be at most {} (got {})",
                limits::PTS_PER_RAY,
                self.sampler.n_pts_per_ray_fine
            );
        }
        self.validate_renderer()?;
        self.validate_sampler()?;
        self.validate_cameras()?;
        match &self.implicit_function {
            ImplicitFunctionConfig::SdfVolume(s) => validate_sdf(s)?,
            ImplicitFunctionConfig::Nerf(n) => validate_nerf(n)?,
            ImplicitFunctionConfig::Ngp(n) => {
                n.params()?;
            }
        }
        self.validate_data_cameras()?;
        self.validate_training()
    }

    /// The `renderer` section, and that its accelerations have a NeRF to work on.
    fn validate_renderer(&self) -> Result<()> {
        if self.renderer.chunk_size == 0 {
            bail!("renderer.chunk_size: must be at least 1");
        }
        let early = self.renderer.early_termination;
        finite("renderer.early_termination", early)?;
        if !(0.0..1.0).contains(&early) {
            bail!("renderer.early_termination: must be in [0, 1) (got {early})");
        }
        if let Some(g) = &self.renderer.occupancy_grid {
            validate_occupancy_grid(g)?;
        }
        let accelerated = early > 0.0 || self.renderer.occupancy_grid.is_some();
        if accelerated && matches!(self.implicit_function, ImplicitFunctionConfig::SdfVolume(_)) {
            bail!("renderer.occupancy_grid and renderer.early_termination need implicit_function.type nerf or ngp");
        }
        if accelerated && self.sampler.n_pts_per_ray_fine > 0 {
            bail!("sampler.n_pts_per_ray_fine (coarse-to-fine sampling) renders densely: set renderer.occupancy_grid=null and renderer.early_termination=0");
        }
        Ok(())
    }

    /// The `sampler` depth range.
    fn validate_sampler(&self) -> Result<()> {
        finite("sampler.min_depth", self.sampler.min_depth)?;
        finite("sampler.max_depth", self.sampler.max_depth)?;
        if self.sampler.min_depth < 0.0 {
            bail!(
                "sampler.min_depth: must be non-negative (got {})",
                self.sampler.min_depth
            );
        }
        if self.sampler.min_depth > self.sampler.max_depth {
            bail!(
                "sampler.min_depth: must not exceed sampler.max_depth ({} > {})",
                self.sampler.min_depth,
                self.sampler.max_depth
            );
        }
        Ok(())
    }

    /// The `cameras` section, and the pixel count of all its frames.
    fn validate_cameras(&self) -> Result<()> {
        let [w, h] = self.data.image_size;
        let c = &self.cameras;
        finite("cameras.radius", c.radius)?;
        finite("cameras.focal_length", c.focal_length)?;
        for (i, v) in c.up.iter().enumerate() {
            finite(&format!("cameras.up[{i}]"), *v)?;
        }
        if c.radius <= 0.0 {
            bail!("cameras.radius: must be positive (got {})", c.radius);
        }
        if c.focal_length <= 0.0 {
            bail!(
                "cameras.focal_length: must be positive (got {})",
                c.focal_length
            );
        }
        count_in_range("cameras.n_poses", c.n_poses, limits::POSES)?;
        if c.n_poses * w * h > limits::FRAME_PIXELS {
            bail!(
                "cameras.n_poses: {} frames of {w}x{h} exceed {} pixels in all (fewer poses or a smaller data.image_size)",
                c.n_poses,
                limits::FRAME_PIXELS
            );
        }
        if c.up.iter().all(|v| *v == 0.0) {
            bail!("cameras.up: must be a non-zero vector");
        }
        Ok(())
    }

    /// The `training` section, when present.
    fn validate_training(&self) -> Result<()> {
        let Some(t) = &self.training else {
            return Ok(());
        };
        for (key, v) in [
            ("training.lr", t.lr),
            ("training.lr_scheduler_gamma", t.lr_scheduler_gamma),
        ] {
            if let Some(v) = v {
                finite(key, v)?;
                if v <= 0.0 {
                    bail!("{key}: must be positive (got {v})");
                }
            }
        }
        if let Some(batch) = t.batch_size {
            let samples =
                batch.saturating_mul(self.sampler.n_pts_per_ray + self.sampler.n_pts_per_ray_fine);
            if samples > limits::BATCH_SAMPLES {
                bail!(
                    "training.batch_size: {batch} rays x {} points is {samples} samples per step, more than {}",
                    self.sampler.n_pts_per_ray + self.sampler.n_pts_per_ray_fine,
                    limits::BATCH_SAMPLES
                );
            }
        }
        for (key, v) in [
            ("training.num_epochs", t.num_epochs),
            ("training.batch_size", t.batch_size),
            ("training.lr_scheduler_step_size", t.lr_scheduler_step_size),
            ("training.checkpoint_interval", t.checkpoint_interval),
            ("training.render_interval", t.render_interval),
        ] {
            if v == Some(0) {
                bail!("{key}: must be at least 1");
            }
        }
        Ok(())
    }

    /// `data.cameras`: finite values, a positive focal length, a non-zero up vector and an eye
    /// away from the scene centre (else pytorch3d's look-at divides by zero).
    fn validate_data_cameras(&self) -> Result<()> {
        let Some(cameras) = &self.data.cameras else {
            return Ok(());
        };
        if cameras.0.len() > limits::POSES {
            bail!("data.cameras: at most {} cameras", limits::POSES);
        }
        for (name, c) in &cameras.0 {
            let key = format!("data.cameras.{name}");
            let values = c
                .eye
                .iter()
                .chain(&c.scene_center)
                .chain(&c.up)
                .chain(&c.principal_point)
                .chain([&c.focal]);
            for v in values {
                finite(&key, *v)?;
            }
            if c.focal <= 0.0 {
                bail!("{key}.focal: must be positive (got {})", c.focal);
            }
            if c.up.iter().all(|v| *v == 0.0) {
                bail!("{key}.up: must be a non-zero vector");
            }
            let d: f64 = (0..3).map(|k| (c.eye[k] - c.scene_center[k]).powi(2)).sum();
            if d.sqrt() < 1e-5 {
                bail!(
                    "{key}.eye: equals scene_center {:?}, so the camera has no viewing direction",
                    c.scene_center
                );
            }
        }
        Ok(())
    }
}

/// The homework's render views: radius 3 with y up and focal 1 for SDF scenes; radius 4 with
/// z up and focal 2 for NeRF scenes; 20 poses.
fn default_cameras(f: &ImplicitFunctionConfig) -> CamerasConfig {
    match f {
        ImplicitFunctionConfig::SdfVolume(_) => CamerasConfig {
            radius: 3.0,
            n_poses: 20,
            up: [0.0, 1.0, 0.0],
            focal_length: 1.0,
        },
        ImplicitFunctionConfig::Nerf(_) | ImplicitFunctionConfig::Ngp(_) => CamerasConfig {
            radius: 4.0,
            n_poses: 20,
            up: [0.0, 0.0, 1.0],
            focal_length: 2.0,
        },
    }
}

fn validate_occupancy_grid(g: &OccupancyGridConfig) -> Result<()> {
    let key = "renderer.occupancy_grid";
    if g.resolution == 0 || g.resolution > 512 {
        bail!("{key}.resolution: must be 1 to 512 (got {})", g.resolution);
    }
    for (i, v) in g.aabb.iter().enumerate() {
        finite(&format!("{key}.aabb[{i}]"), *v)?;
    }
    for k in 0..3 {
        if g.aabb[k] >= g.aabb[k + 3] {
            bail!(
                "{key}.aabb: min must be below max on every axis (axis {k}: {} >= {})",
                g.aabb[k],
                g.aabb[k + 3]
            );
        }
    }
    finite(&format!("{key}.alpha_threshold"), g.alpha_threshold)?;
    if !(g.alpha_threshold > 0.0 && g.alpha_threshold < 1.0) {
        bail!(
            "{key}.alpha_threshold: must be in (0, 1) (got {})",
            g.alpha_threshold
        );
    }
    finite(&format!("{key}.decay"), g.decay)?;
    if !(g.decay > 0.0 && g.decay <= 1.0) {
        bail!("{key}.decay: must be in (0, 1] (got {})", g.decay);
    }
    if g.update_interval == 0 {
        bail!("{key}.update_interval: must be at least 1");
    }
    Ok(())
}

fn finite(key: &str, v: f64) -> Result<()> {
    if !v.is_finite() {
        bail!("{key}: must be a finite number (got {v})");
    }
    Ok(())
}

fn validate_sdf(s: &SdfVolumeConfig) -> Result<()> {
    let p = "implicit_function";
    for (i, v) in s.sdf.center.val.iter().enumerate() {
        finite(&format!("{p}.sdf.center.val[{i}]"), *v)?;
    }
    for (i, v) in s.feature.val.iter().enumerate() {
        finite(&format!("{p}.feature.val[{i}]"), *v)?;
    }
    finite(&format!("{p}.alpha.val"), s.alpha.val)?;
    finite(&format!("{p}.beta.val"), s.beta.val)?;
    if !(0.0..=1.0).contains(&s.alpha.val) {
        bail!("{p}.alpha.val: must be in [0, 1] (got {})", s.alpha.val);
    }
    if s.beta.val <= 0.0 {
        bail!("{p}.beta.val: must be positive (got {})", s.beta.val);
    }
    match s.sdf.kind {
        SdfKind::Box => {
            let Some(sides) = &s.sdf.side_lengths else {
                bail!("{p}.sdf.side_lengths: required for a box");
            };
            for (i, v) in sides.val.iter().enumerate() {
                finite(&format!("{p}.sdf.side_lengths.val[{i}]"), *v)?;
                if *v <= 0.0 {
                    bail!("{p}.sdf.side_lengths.val[{i}]: must be positive (got {v})");
                }
            }
        }
        SdfKind::Sphere => {
            let Some(radius) = &s.sdf.radius else {
                bail!("{p}.sdf.radius: required for a sphere");
            };
            finite(&format!("{p}.sdf.radius.val"), radius.val)?;
            if radius.val <= 0.0 {
                bail!("{p}.sdf.radius.val: must be positive (got {})", radius.val);
            }
        }
    }
    Ok(())
}

fn validate_nerf(n: &NerfConfig) -> Result<()> {
    let p = "implicit_function";
    count_in_range(
        &format!("{p}.n_hidden_neurons_xyz"),
        n.n_hidden_neurons_xyz,
        limits::HIDDEN,
    )?;
    count_in_range(
        &format!("{p}.n_hidden_neurons_dir"),
        n.n_hidden_neurons_dir,
        limits::HIDDEN,
    )?;
    count_in_range(&format!("{p}.n_layers_xyz"), n.n_layers_xyz, limits::LAYERS)?;
    for (key, v) in [
        ("n_harmonic_functions_xyz", n.n_harmonic_functions_xyz),
        ("n_harmonic_functions_dir", n.n_harmonic_functions_dir),
    ] {
        if v > limits::HARMONICS {
            bail!("{p}.{key}: must be at most {} (got {v})", limits::HARMONICS);
        }
    }
    finite(&format!("{p}.density_noise_std"), n.density_noise_std)?;
    if n.density_noise_std < 0.0 {
        bail!("{p}.density_noise_std: must be non-negative");
    }
    if let Some(bad) = n
        .append_xyz
        .iter()
        .find(|&&i| i == 0 || i >= n.n_layers_xyz)
    {
        bail!(
            "{p}.append_xyz: layer {bad} is out of range 1..{}",
            n.n_layers_xyz
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn box_with(overrides: &[&str]) -> Result<Config> {
        let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        Config::load("box", &o)
    }

    #[test]
    fn ngp_keys_and_defaults() {
        let lego =
            std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/lego.yaml"))
                .unwrap();
        let start = lego.find("implicit_function:").unwrap();
        let end = lego.find("cameras:").unwrap();
        let yaml = |body: &str| {
            format!(
                "{}implicit_function:\n{body}\n{}",
                &lego[..start],
                &lego[end..]
            )
        };
        let c = Config::from_yaml(&yaml("  type: ngp"), &[]).unwrap();
        let ImplicitFunctionConfig::Ngp(n) = &c.implicit_function else {
            panic!("not ngp")
        };
        let p = n.params().unwrap();
        assert_eq!(
            (p.grid.n_levels, p.grid.n_features, p.grid.log2_table_size),
            (16, 2, 19)
        );
        assert_eq!(
            (p.grid.base_resolution, p.grid.max_resolution),
            (16.0, 3072.0)
        );
        assert_eq!(p.aabb, [[-1.5; 3], [1.5; 3]]);
        let o = vec!["implicit_function.log2_hashmap_size=12".to_string()];
        let c = Config::from_yaml(&yaml("  type: ngp\n  max_resolution: 512"), &o).unwrap();
        let ImplicitFunctionConfig::Ngp(n) = &c.implicit_function else {
            panic!("not ngp")
        };
        assert_eq!(n.params().unwrap().grid.max_resolution, 512.0);
        assert_eq!(n.params().unwrap().grid.log2_table_size, 12);
        assert!(c.nerf_params().unwrap_err().to_string().contains("ngp"));
        for bad in [
            "  type: ngp\n  density_activation: relu",
            "  type: ngp\n  log2_hashmap_size: 30",
            "  type: ngp\n  aabb: [[1, 1, 1], [0, 2, 2]]",
            "  type: ngp\n  n_hidden: 3",
        ] {
            let e = Config::from_yaml(&yaml(bad), &[]).unwrap_err().to_string();
            assert!(!e.contains('\n'), "{e}");
        }
    }

    #[test]
    fn an_ngp_checkpoint_saves_and_loads_for_rendering() {
        use crate::field::ngp::Ngp;
        let lego =
            std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/configs/lego.yaml"))
                .unwrap();
        let start = lego.find("implicit_function:").unwrap();
        let end = lego.find("cameras:").unwrap();
        let body = "implicit_function:\n  type: ngp\n  n_levels: 4\n  log2_hashmap_size: 10\n  max_resolution: 64\n";
        let c =
            Config::from_yaml(&format!("{}{body}{}", &lego[..start], &lego[end..]), &[]).unwrap();
        let ImplicitFunctionConfig::Ngp(n) = &c.implicit_function else {
            panic!("not ngp")
        };
        let dev = candle_core::Device::Cpu;
        let varmap = candle_nn::VarMap::new();
        let vb = candle_nn::VarBuilder::from_varmap(&varmap, candle_core::DType::F32, &dev);
        let model = Ngp::new(&n.params().unwrap(), vb).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ngp.safetensors");
        let tensors = crate::io::checkpoint::model_tensors(&varmap);
        crate::io::checkpoint::save(&path, &tensors, Default::default()).unwrap();
        let field = c.load_field(&path, &dev).unwrap();
        assert!(field.supports_packed() && field.occupancy().is_some());
        let points = candle_core::Tensor::rand(-1.4f32, 1.4, (50, 3), &dev).unwrap();
        let dirs = candle_core::Tensor::new(&[[0f32, 0.6, 0.8]], &dev).unwrap();
        let rays = candle_core::Tensor::zeros(50, candle_core::DType::U32, &dev).unwrap();
        let (s0, c0) = model.forward_packed(&points, &rays, &dirs).unwrap();
        let (s1, c1) = field.evaluate_packed(&points, &rays, &dirs).unwrap();
        let diff = crate::core::compare::max_abs_difference;
        assert_eq!(diff(&s0, &s1).unwrap() + diff(&c0, &c1).unwrap(), 0.0);
        // A checkpoint of other sizes is refused in one line.
        let o = vec!["implicit_function.log2_hashmap_size=11".to_string()];
        let other =
            Config::from_yaml(&format!("{}{body}{}", &lego[..start], &lego[end..]), &o).unwrap();
        let e = format!("{:#}", other.load_field(&path, &dev).err().unwrap());
        assert!(e.contains("encoding.table") || e.contains("shape"), "{e}");
    }

    #[test]
    fn built_in_box_matches_the_homework() {
        let c = box_with(&[]).unwrap();
        assert_eq!(c.image_size(), (256, 256));
        assert_eq!(c.sampler.n_pts_per_ray, 64);
        assert_eq!((c.sampler.min_depth, c.sampler.max_depth), (0.0, 5.0));
        let ImplicitFunctionConfig::SdfVolume(s) = &c.implicit_function else {
            panic!()
        };
        assert_eq!(s.sdf.side_lengths.as_ref().unwrap().val, [1.75; 3]);
        assert_eq!(s.beta.val, 0.05);
        assert!(s.feature.rainbow);
        assert_eq!(c.cameras.radius, 3.0);
    }

    #[test]
    fn overrides_change_values() {
        let c = box_with(&[
            "sampler.n_pts_per_ray=32",
            "data.image_size=[200,150]",
            "renderer.white_background=True",
        ])
        .unwrap();
        assert_eq!(c.sampler.n_pts_per_ray, 32);
        assert_eq!(c.image_size(), (200, 150));
        assert!(c.renderer.white_background);
        let c = box_with(&[
            "implicit_function.sdf.type=sphere",
            "implicit_function.sdf.radius.val=0.8",
        ])
        .unwrap();
        assert!(matches!(
            c.sdf_volume().unwrap().sdf,
            crate::core::sdf::Sdf::Sphere { .. }
        ));
    }

    fn err(overrides: &[&str]) -> String {
        format!("{:#}", box_with(overrides).unwrap_err())
    }

    #[test]
    fn errors_name_the_key() {
        assert!(err(&["sampler.n_pts_per_rays=3"]).contains("n_pts_per_rays"));
        assert!(err(&["sampler.n_pts_per_ray=abc"]).contains("sampler.n_pts_per_ray"));
        assert!(err(&["sampler.n_pts_per_ray=0"]).contains("sampler.n_pts_per_ray"));
        assert!(err(&["sampler.min_depth=-1"]).contains("sampler.min_depth"));
        assert!(err(&["sampler.min_depth=6"]).contains("sampler.min_depth"));
        assert!(err(&["data.image_size=[0,5]"]).contains("data.image_size"));
        assert!(err(&["renderer.chunk_size=0"]).contains("renderer.chunk_size"));
        assert!(err(&["implicit_function.beta.val=.nan"]).contains("implicit_function.beta.val"));
        assert!(err(&["implicit_function.sdf.center.val=[0, .inf, 0]"]).contains("center"));
        assert!(err(&["implicit_function.sdf.colour=1"]).contains("implicit_function.sdf"));
        assert!(err(&["implicit_function.type=mesh"]).contains("implicit_function.type"));
        assert!(err(&["cameras.radius=.nan"]).contains("cameras"));
        assert!(err(&["nokey"]).contains("key.sub=value"));
    }

    #[test]
    fn malformed_yaml_and_missing_configs() {
        assert!(
            format!("{:#}", Config::from_yaml("data: [1, 2", &[]).unwrap_err())
                .contains("malformed")
        );
        assert!(
            format!("{:#}", Config::load("no_such_config", &[]).unwrap_err()).contains("not found")
        );
    }
}
