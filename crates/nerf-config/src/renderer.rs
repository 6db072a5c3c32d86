//! The `renderer` section: the volume renderer and its accelerations (early termination, the
//! occupancy grid), with what they become at run time.

use anyhow::Result;
use serde::Deserialize;

use super::Config;
use nerf_core::contraction::Contraction;
use nerf_render::occupancy::{density_threshold, OccupancyGridParams};
use nerf_render::renderer::{VolumeRenderer, BLACK, WHITE};
use nerf_render::sampler_kind::SamplerSettings;
use nerf_render::view::RenderSettings;
use nerf_train::fit::GridSchedule;

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
    /// Extension, `renderer.background`: `auto`, `white`, `black` or `[r, g, b]` (in [0, 1]);
    /// when given it decides the background instead of `white_background`
    /// ([`BackgroundConfig`]).
    #[serde(default)]
    pub background: Option<BackgroundConfig>,
    /// Extension: stop marching a ray once its transmittance falls below this (0 = off, the
    /// homework's dense rendering). Needs a NeRF field.
    #[serde(default)]
    pub early_termination: f64,
    /// Extension: skip samples in empty cells of an occupancy grid (NeRF fields).
    pub occupancy_grid: Option<OccupancyGridConfig>,
}

/// `renderer.background` (extension): the colour behind the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BackgroundConfig {
    /// `auto`: training picks it from the photos (a random colour per step when they have
    /// alpha, stored as white; else the colour of a plain backdrop their borders show, else
    /// black) and stores it in the checkpoint, where eval, render and view read it.
    Auto,
    /// A colour, RGB in [0, 1] (`white`, `black` or `[r, g, b]`).
    Colour([f32; 3]),
}

impl<'de> Deserialize<'de> for BackgroundConfig {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Name(String),
            Rgb([f32; 3]),
        }
        let bad = || {
            serde::de::Error::custom(
                "expected auto, white, black or [r, g, b] with each value in [0, 1]",
            )
        };
        match Raw::deserialize(d).map_err(|_| bad())? {
            Raw::Name(n) => match n.to_ascii_lowercase().as_str() {
                "auto" => Ok(Self::Auto),
                "white" => Ok(Self::Colour(WHITE)),
                "black" => Ok(Self::Colour(BLACK)),
                _ => Err(bad()),
            },
            Raw::Rgb(c) if c.iter().all(|v| (0.0..=1.0).contains(v)) => Ok(Self::Colour(c)),
            Raw::Rgb(_) => Err(bad()),
        }
    }
}

/// `renderer.type`: the homework's one renderer.
#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum RendererKind {
    /// `volume`: the homework's `VolumeRenderer`.
    #[default]
    Volume,
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
    /// Training with `renderer.background: auto` on photos that show no plain backdrop (a
    /// room, a street): the decay used instead of `decay` (default: `decay`).
    #[serde(default)]
    pub decay_without_backdrop: Option<f64>,
    /// Training: keep empty the cells within this fraction of each training camera's
    /// distance from the origin around that camera (0 = off, the default; in [0, 1)).
    #[serde(default)]
    pub camera_clearance: f64,
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
            decay_without_backdrop: None,
            camera_clearance: 0.0,
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
fn d64() -> usize {
    64
}

impl RendererConfig {
    /// The renderer: chunk size, background, early termination (the occupancy grid belongs to
    /// the field; see [`OccupancyGridConfig::params`]).
    pub(crate) fn renderer(&self) -> Result<VolumeRenderer> {
        let renderer = VolumeRenderer::new(self.chunk_size, self.white_background)?
            .with_early_termination(self.early_termination)?;
        Ok(match self.background {
            Some(BackgroundConfig::Colour(c)) => renderer.with_background(c),
            // Until training or a checkpoint decides it: `white_background`.
            Some(BackgroundConfig::Auto) | None => renderer,
        })
    }

    /// Whether the background is chosen from the photos and stored (`background: auto`).
    pub fn background_is_auto(&self) -> bool {
        self.background == Some(BackgroundConfig::Auto)
    }
}

impl OccupancyGridConfig {
    /// The grid, with its density threshold: `alpha_threshold` opacity over one sample step
    /// of `sampler` ([`SamplerSettings::step`]); its box is in the space `contraction` maps
    /// world points into (the field's).
    pub(crate) fn params(
        &self,
        sampler: &SamplerSettings,
        contraction: Contraction,
    ) -> OccupancyGridParams {
        OccupancyGridParams {
            resolution: self.resolution,
            aabb: self.aabb,
            density_threshold: density_threshold(self.alpha_threshold, sampler.step()),
            contraction,
        }
    }

    /// How training keeps the grid ([`OccupancyGridConfig::params`]) up to date.
    pub(crate) fn schedule(
        &self,
        sampler: &SamplerSettings,
        contraction: Contraction,
    ) -> GridSchedule {
        GridSchedule {
            grid: self.params(sampler, contraction),
            update_interval: self.update_interval,
            warmup_steps: self.warmup_steps,
            decay: self.decay,
            camera_clearance: self.camera_clearance,
            keep_far_shell: false,
        }
    }
}

impl Config {
    /// The `renderer` section as a renderer (`RendererConfig::renderer`).
    pub fn renderer(&self) -> Result<VolumeRenderer> {
        self.renderer.renderer()
    }

    /// The `sampler` and `renderer` sections together, to pair with a field
    /// ([`RenderSettings::with`]).
    pub fn render_settings(&self) -> Result<RenderSettings> {
        Ok(RenderSettings {
            sampler: self.sampler()?,
            renderer: self.renderer()?,
        })
    }

    /// The occupancy grid the renderer uses, with its density threshold
    /// (`OccupancyGridConfig::params`), or `None` when the config has no grid.
    pub fn occupancy_grid(&self) -> Option<OccupancyGridParams> {
        let g = self.renderer.occupancy_grid.as_ref()?;
        Some(g.params(&self.sampler, self.contraction()))
    }

    /// How training keeps the occupancy grid up to date, when the config has one.
    pub(crate) fn grid_schedule(&self) -> Option<GridSchedule> {
        let g = self.renderer.occupancy_grid.as_ref()?;
        Some(g.schedule(&self.sampler, self.contraction()))
    }
}
