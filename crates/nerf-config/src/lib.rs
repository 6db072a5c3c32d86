//! Configuration in the homework's YAML schema, with Hydra-style `key.sub=value` overrides.
//!
//! A homework config file works unmodified. Unknown keys, wrong types and bad values are
//! errors that name the key ([`ConfigError`]). Extensions beyond the homework (all optional):
//! `cameras` (the surround views to render) and `data.data_dir` (where the dataset lives).
//!
//! One file per concern: where the text comes from (`built_in`), the overrides
//! (`overrides`), the words of errors (`messages`), the range checks (`validation`), and
//! one file per section holding its schema and what it becomes at run time (`data`,
//! `sampler`, `renderer`, `cameras`, `training`; the `implicit_function` section's
//! schema in `implicit_function`, its fields in `field_section`); which checkpoint a
//! command uses is `checkpoint_paths`'s.

pub(crate) mod built_in;
pub(crate) mod cameras;
pub(crate) mod checkpoint_paths;
pub(crate) mod config_error;
pub(crate) mod data;
pub(crate) mod field_section;
pub(crate) mod implicit_function;
pub mod limits;
pub(crate) mod messages;
pub(crate) mod overrides;
pub(crate) mod renderer;
pub(crate) mod sampler;
pub(crate) mod training;
pub(crate) mod validation;
pub mod yaml_bounds;

use anyhow::Result;
use serde::Deserialize;
use serde_yaml_ng::Value;

use cameras::RawCamerasConfig;
use messages::{blame, from_value, one_line};

pub use built_in::config_text;
pub(crate) use cameras::CamerasConfig;
pub use checkpoint_paths::SHIPPED_NGP_CHECKPOINT;
pub use config_error::ConfigError;
pub use data::{
    photo_scale_factor, DataCameraConfig, DataCameras, DataConfig, SizeUse, DEFAULT_PIXEL_BUDGET,
};
pub(crate) use implicit_function::ImplicitFunctionConfig;
pub use messages::{in_user_words, plural};
use nerf_render::sampler_kind::SamplerSettings;
pub use overrides::apply_override;
pub use renderer::{BackgroundConfig, OccupancyGridConfig, RendererConfig, RendererKind};
pub use training::TrainingConfig;

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

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    seed: Option<u64>,
    #[serde(rename = "type", default)]
    kind: Option<JobKind>,
    data: DataConfig,
    renderer: RendererConfig,
    sampler: SamplerSettings,
    implicit_function: Value,
    training: Option<TrainingConfig>,
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
    pub sampler: SamplerSettings,
    /// The `implicit_function` section, typed by its `type`.
    pub implicit_function: ImplicitFunctionConfig,
    /// The `training` section, when present (needed to train).
    pub training: Option<TrainingConfig>,
    /// The `cameras` section, any key left out taking the scene type's default.
    pub cameras: CamerasConfig,
}

impl Config {
    /// Loads `--config NAME_OR_PATH` and applies the overrides in order. Errors: see
    /// [`ConfigError`]; a bad value's message says the override or file line it came from.
    pub fn load(name_or_path: &str, overrides: &[String]) -> Result<Self, ConfigError> {
        let (text, origin) = config_text(name_or_path)?;
        Self::parse(&text, overrides)
            .map_err(|e| ConfigError::from_anyhow(blame(&text, &origin, overrides, e)))
    }

    /// Parses YAML text, applies overrides, and validates. Errors: see [`ConfigError`].
    pub fn from_yaml(text: &str, overrides: &[String]) -> Result<Self, ConfigError> {
        Self::parse(text, overrides).map_err(ConfigError::from_anyhow)
    }

    /// [`Config::from_yaml`], its typed errors inside an `anyhow::Error`.
    fn parse(text: &str, overrides: &[String]) -> Result<Self> {
        let syntax = |message: String| ConfigError::Syntax { message };
        yaml_bounds::check_yaml_bounds(text, "the config").map_err(|e| syntax(format!("{e:#}")))?;
        let mut root: Value = serde_yaml_ng::from_str(text)
            .map_err(|e| syntax(format!("malformed YAML: {}", one_line(&e.to_string()))))?;
        if !matches!(root, Value::Mapping(_)) {
            let message = "malformed config: the top level must be a mapping of sections";
            return Err(syntax(message.to_string()).into());
        }
        for o in overrides {
            apply_override(&mut root, o)?;
        }
        let raw: RawConfig = from_value(root, "")?;
        let implicit_function = ImplicitFunctionConfig::from_section(raw.implicit_function)?;
        let cameras = CamerasConfig::resolve(raw.cameras, &implicit_function);
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
}

/// The built-in `box` config with `overrides` (for tests).
#[cfg(test)]
fn test_box_with(overrides: &[&str]) -> Result<Config> {
    let o: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    Ok(Config::load("box", &o)?)
}
