//! The lego study: a trained checkpoint at several samples per ray with each acceleration the
//! renderer offers, coarse-to-fine sampling and the hash-grid model, against the ground truth
//! and the dense render.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use candle_core::Device;
use serde::{Serialize, Serializer};

use super::scoring::timed_frames;
use super::{ReportOptions, Sizes};
use crate::bench::mean_psnr_of_views;
use nerf::config::Config;
use nerf::core::camera::PerspectiveCamera;
use nerf::render::view::RenderedView;
use nerf::RgbImage;

/// How a lego row is rendered: the MLP with each acceleration the renderer offers, the MLP
/// coarse-to-fine, or the hash-grid model. Identifies the study's rows; written as its
/// [`LegoMethod::name`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LegoMethod {
    /// The MLP, every sample evaluated.
    Dense,
    /// The MLP, marching stopped once a ray is opaque.
    EarlyTermination,
    /// The MLP, samples in empty occupancy-grid cells skipped.
    OccupancyGrid,
    /// The MLP with both accelerations (the `lego` config as shipped).
    GridAndEarlyTermination,
    /// The MLP rendered densely at `n/2` stratified depths and `n/2` more drawn from their
    /// weights ([`nerf::render::hierarchical`]).
    CoarseToFine,
    /// The hash-grid model (the `lego_ngp` config) with both accelerations.
    HashGrid,
}

impl LegoMethod {
    /// The accelerations of the MLP, in the order of the study's rows.
    pub const ACCELERATIONS: [LegoMethod; 4] = [
        LegoMethod::Dense,
        LegoMethod::EarlyTermination,
        LegoMethod::OccupancyGrid,
        LegoMethod::GridAndEarlyTermination,
    ];

    /// Every method, in the order of the study's rows and the plot's legend.
    pub const ALL: [LegoMethod; 6] = [
        LegoMethod::Dense,
        LegoMethod::EarlyTermination,
        LegoMethod::OccupancyGrid,
        LegoMethod::GridAndEarlyTermination,
        LegoMethod::CoarseToFine,
        LegoMethod::HashGrid,
    ];

    /// The name shown in the report's tables, plot and JSON.
    pub fn name(self) -> &'static str {
        match self {
            LegoMethod::Dense => "dense",
            LegoMethod::EarlyTermination => "early termination",
            LegoMethod::OccupancyGrid => "occupancy grid",
            LegoMethod::GridAndEarlyTermination => "grid + early termination",
            LegoMethod::CoarseToFine => "coarse-to-fine (n/2 coarse + n/2 fine)",
            LegoMethod::HashGrid => "hash grid (grid + early termination)",
        }
    }

    /// Whether the renderer stops marching opaque rays (`renderer.early_termination` as the
    /// config has it, else 0).
    fn early_termination(self) -> bool {
        matches!(
            self,
            LegoMethod::EarlyTermination
                | LegoMethod::GridAndEarlyTermination
                | LegoMethod::HashGrid
        )
    }

    /// Whether the renderer skips empty cells (`renderer.occupancy_grid` as the config has
    /// it, else none).
    fn occupancy_grid(self) -> bool {
        matches!(
            self,
            LegoMethod::OccupancyGrid | LegoMethod::GridAndEarlyTermination | LegoMethod::HashGrid
        )
    }
}

impl Serialize for LegoMethod {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// One render of the lego study: how, at how many samples per ray, at what size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LegoRender {
    /// How it is rendered.
    pub method: LegoMethod,
    /// Samples per ray a ray keeps (coarse-to-fine: half stratified, half drawn).
    pub n_pts: usize,
    /// Width and height in pixels.
    pub size: usize,
}

impl LegoRender {
    /// The config that renders it, validated: `lego_ngp` for the hash grid, else `lego` (which
    /// has both accelerations on) with the ones the method leaves out turned off
    /// (`renderer.early_termination` 0, `renderer.occupancy_grid` none).
    pub fn config(&self) -> Result<Config> {
        let name = match self.method {
            LegoMethod::HashGrid => "lego_ngp",
            _ => "lego",
        };
        let mut config = Config::load(name, &[])?;
        config.data.image_size = Some([self.size, self.size]);
        config.sampler.n_pts_per_ray = self.n_pts;
        if !self.method.early_termination() {
            config.renderer.early_termination = 0.0;
        }
        if !self.method.occupancy_grid() {
            config.renderer.occupancy_grid = None;
        }
        if self.method == LegoMethod::CoarseToFine {
            let half = (self.n_pts / 2).max(1);
            config.sampler.n_pts_per_ray = half;
            config.sampler.n_pts_per_ray_fine = self.n_pts - half;
        }
        config.validate()?;
        Ok(config)
    }
}

/// One sample count and acceleration of the lego study.
#[derive(Debug, Clone, Serialize)]
pub struct LegoRow {
    /// How the row was rendered (written as its name, [`LegoMethod::name`]).
    pub acceleration: LegoMethod,
    /// Samples per ray (`n_pts_per_ray`).
    pub n_pts: usize,
    /// Mean over the views of the fastest of the repeats.
    pub seconds_per_frame: f64,
    /// Mean PSNR against the test images.
    pub psnr_vs_truth: f64,
    /// Mean PSNR against the dense render at `reference_pts`.
    pub psnr_vs_dense: f64,
    /// Fraction of the samples at which the field was evaluated.
    pub evaluated: f64,
}

/// The trained NeRF at several sample counts and accelerations.
#[derive(Debug, Clone, Serialize)]
pub struct LegoStudy {
    /// The checkpoint rendered.
    pub checkpoint: PathBuf,
    /// Width and height of the renders, in pixels.
    pub size: usize,
    /// Test views rendered.
    pub views: usize,
    /// Samples per ray of the dense reference render.
    pub reference_pts: usize,
    /// One row per acceleration and sample count.
    pub rows: Vec<LegoRow>,
}

/// The lego study, or why it was skipped.
pub fn lego_study(
    options: &ReportOptions,
    sizes: &Sizes,
    device: &Device,
    progress: &nerf::io::progress::Progress,
) -> Result<LegoStudy> {
    nerf::io::checkpoint_file::ensure_checkpoint_file(&options.checkpoint)?;
    let size = sizes.lego_size;
    let render = |method, n_pts| LegoRender {
        method,
        n_pts,
        size,
    };
    let base = render(
        LegoMethod::GridAndEarlyTermination,
        sizes.lego_reference_pts,
    )
    .config()?;
    let dataset = nerf::io::dataset::Dataset::load(
        &options.data_dir,
        nerf::io::dataset::Split::Test,
        size,
        size,
        base.renderer.white_background,
    )
    .with_context(|| format!("lego dataset at {}", options.data_dir.display()))?;
    let views = sizes.lego_views.min(dataset.frames.len());
    let cameras = crate::bench::lego_cameras(&dataset, views)?;
    let truth: Vec<RgbImage> = dataset.images.iter().take(views).cloned().collect();
    let run = |config: &Config| -> Result<(Vec<RenderedView>, f64)> {
        let (state, _) = config.load_model(&options.checkpoint, device)?;
        timed_frames(
            config,
            &*state.render_field(),
            &cameras,
            sizes.repeats,
            device,
        )
    };
    let (reference, _) = run(&render(LegoMethod::Dense, sizes.lego_reference_pts).config()?)?;
    let reference: Vec<RgbImage> = reference.into_iter().map(|f| f.color).collect();
    progress.inc(1);
    let mut rows = Vec::new();
    for method in LegoMethod::ACCELERATIONS
        .into_iter()
        .chain([LegoMethod::CoarseToFine])
    {
        for &n in &sizes.lego_pts {
            let (frames, seconds) = run(&render(method, n).config()?)?;
            rows.push(lego_row(
                method,
                n,
                seconds,
                &frames,
                &truth,
                Some(&reference),
            ));
            progress.inc(1);
        }
    }
    if let Some(ngp) = options.ngp_checkpoint.as_ref().filter(|p| p.is_file()) {
        rows.extend(hash_grid_rows(ngp, sizes, &cameras, &truth, device)?);
    }
    Ok(LegoStudy {
        checkpoint: options.checkpoint.clone(),
        size,
        views,
        reference_pts: sizes.lego_reference_pts,
        rows,
    })
}

/// The lego study's hash-grid rows: the checkpoint `ngp` with the `lego_ngp` config at each
/// of the study's sample counts, on `cameras`, scored against `truth`.
fn hash_grid_rows(
    ngp: &Path,
    sizes: &Sizes,
    cameras: &[PerspectiveCamera],
    truth: &[RgbImage],
    device: &Device,
) -> Result<Vec<LegoRow>> {
    let mut rows = Vec::new();
    for &n in &sizes.lego_pts {
        let render = LegoRender {
            method: LegoMethod::HashGrid,
            n_pts: n,
            size: sizes.lego_size,
        };
        let mut config = render.config()?;
        config
            .training
            .get_or_insert_with(Default::default)
            .checkpoint_path = Some(ngp.to_path_buf());
        let field = config.load_field(ngp, device)?;
        let (frames, seconds) = timed_frames(&config, &*field, cameras, sizes.repeats, device)?;
        rows.push(lego_row(
            LegoMethod::HashGrid,
            n,
            seconds,
            &frames,
            truth,
            None,
        ));
    }
    Ok(rows)
}

/// A lego study row of `frames` rendered in `seconds` per frame with `n_pts` samples per
/// ray, scored against `truth` and against the dense `reference` frames (without one,
/// `psnr_vs_dense` is NaN).
fn lego_row(
    acceleration: LegoMethod,
    n_pts: usize,
    seconds: f64,
    frames: &[RenderedView],
    truth: &[RgbImage],
    reference: Option<&[RgbImage]>,
) -> LegoRow {
    let counts = frames
        .iter()
        .fold(nerf::render::skipping::SampleCounts::default(), |a, f| {
            a + f.samples
        });
    LegoRow {
        acceleration,
        n_pts,
        seconds_per_frame: seconds,
        psnr_vs_truth: mean_psnr_of_views(frames, truth),
        psnr_vs_dense: reference.map_or(f64::NAN, |r| mean_psnr_of_views(frames, r)),
        evaluated: counts.evaluated_fraction(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_method_is_the_config_its_overrides_made() {
        // The configs the study rendered from overrides of `lego` (and `lego_ngp`).
        let dense = [
            "renderer.early_termination=0",
            "renderer.occupancy_grid=null",
        ];
        let overrides = |method: LegoMethod| -> (&str, Vec<&str>) {
            match method {
                LegoMethod::Dense => ("lego", dense.to_vec()),
                LegoMethod::EarlyTermination => ("lego", vec!["renderer.occupancy_grid=null"]),
                LegoMethod::OccupancyGrid => ("lego", vec!["renderer.early_termination=0"]),
                LegoMethod::GridAndEarlyTermination => ("lego", vec![]),
                LegoMethod::CoarseToFine => {
                    let mut o = dense.to_vec();
                    o.push("sampler.n_pts_per_ray_fine=33");
                    ("lego", o)
                }
                LegoMethod::HashGrid => ("lego_ngp", vec![]),
            }
        };
        for method in LegoMethod::ALL {
            let (name, extra) = overrides(method);
            let n = if method == LegoMethod::CoarseToFine {
                32
            } else {
                65
            };
            let mut o = vec!["data.image_size=[40,40]".to_string()];
            o.push(format!("sampler.n_pts_per_ray={n}"));
            o.extend(extra.iter().map(|s| s.to_string()));
            let expected = Config::load(name, &o).unwrap();
            let render = LegoRender {
                method,
                n_pts: 65,
                size: 40,
            };
            assert_eq!(render.config().unwrap(), expected, "{}", method.name());
        }
    }

    #[test]
    fn methods_are_written_by_name() {
        let names: Vec<String> = LegoMethod::ALL
            .iter()
            .map(|m| serde_json::to_string(m).unwrap())
            .collect();
        assert_eq!(names[0], "\"dense\"");
        assert_eq!(names[5], "\"hash grid (grid + early termination)\"");
        let unique: std::collections::HashSet<&String> = names.iter().collect();
        assert_eq!(unique.len(), LegoMethod::ALL.len());
    }
}
