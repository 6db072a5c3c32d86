//! The box study: the box scene at increasing samples per ray, against far more samples and,
//! for a hard surface, against the analytic ray–box hit.

use anyhow::{bail, Result};
use candle_core::Device;
use serde::Serialize;

use super::scoring::{
    analytic_image, image_error, stacked, timed_frames, AnalyticImage, ImageError, GRAZING_BETAS,
};
use super::Sizes;
use nerf::config::Config;
use nerf::core::camera::PerspectiveCamera;
use nerf::field::sdf_config::SdfVolumeConfig;

/// β of the homework's box.
pub const HOMEWORK_BETA: f64 = 0.05;
/// β of the hard box, whose surface is sharp enough to compare with the analytic hit.
pub const HARD_BETA: f64 = 1e-4;

/// The box scenes the report studies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoxScene {
    /// The homework's box (β = [`HOMEWORK_BETA`]), compared with many samples only: its
    /// renders have no limit as samples are added.
    Homework,
    /// The hard box (β = [`HARD_BETA`]), compared with many samples and with the analytic
    /// surface it converges to.
    Hard,
}

impl BoxScene {
    /// The volume's β.
    pub fn beta(self) -> f64 {
        match self {
            BoxScene::Homework => HOMEWORK_BETA,
            BoxScene::Hard => HARD_BETA,
        }
    }

    /// Whether the study compares with the analytic surface.
    pub fn against_analytic(self) -> bool {
        self == BoxScene::Hard
    }
}

/// One render of the box study: the built-in `box` config at one β, image size and sample
/// count.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxRender {
    /// The volume's β (`implicit_function.beta.val`).
    pub beta: f64,
    /// Width and height in pixels (`data.image_size`).
    pub size: usize,
    /// Samples per ray (`sampler.n_pts_per_ray`).
    pub n_pts: usize,
}

impl BoxRender {
    /// The `box` config with these settings, validated.
    pub fn config(&self) -> Result<Config> {
        let mut config = Config::load("box", &[])?;
        let Some(volume) = config.implicit_function.get_mut::<SdfVolumeConfig>() else {
            bail!("the box config's implicit_function is not an sdf_volume");
        };
        volume.beta.val = self.beta;
        config.data.image_size = Some([self.size, self.size]);
        config.sampler.n_pts_per_ray = self.n_pts;
        config.validate()?;
        Ok(config)
    }
}

/// One sample count of a box study.
#[derive(Debug, Clone, Serialize)]
pub struct BoxRow {
    /// Samples per ray (`n_pts_per_ray`).
    pub n_pts: usize,
    /// Mean over the views of the fastest of the repeats.
    pub seconds_per_frame: f64,
    /// Against the same scene at `reference_pts` samples.
    pub vs_reference: ImageError,
    /// Against the analytic surface (hard box only): colour at the hit point (0 on a miss),
    /// depth on the pixels whose ray hits.
    pub vs_analytic: Option<ImageError>,
    /// The same without the grazing misses (within [`GRAZING_BETAS`]·β of the surface).
    pub vs_analytic_clear: Option<ImageError>,
    /// Grazing misses left out of `vs_analytic_clear`, over all views.
    pub grazing_pixels: usize,
}

/// The box scene at increasing sample counts.
#[derive(Debug, Clone, Serialize)]
pub struct BoxStudy {
    /// The volume's β.
    pub beta: f64,
    /// Samples per ray of the reference render.
    pub reference_pts: usize,
    /// One row per sample count, in increasing order.
    pub rows: Vec<BoxRow>,
}

/// The box `scene` at every sample count of `sizes`, against `sizes.box_reference_pts`
/// samples and, for the hard box, against the analytic surface.
pub fn box_study(
    scene: BoxScene,
    sizes: &Sizes,
    device: &Device,
    progress: &nerf::io::progress::Progress,
) -> Result<BoxStudy> {
    let (beta, size) = (scene.beta(), sizes.box_size);
    let render = |n_pts| BoxRender { beta, size, n_pts };
    let reference_config = render(sizes.box_reference_pts).config()?;
    let field = reference_config.sdf_field(device)?;
    let volume = reference_config.sdf_volume()?;
    let all_cameras = reference_config.surround_cameras();
    let cameras: Vec<PerspectiveCamera> = sizes
        .box_views
        .iter()
        .map(|&v| all_cameras[v % all_cameras.len()])
        .collect();
    let (reference, _) = timed_frames(&reference_config, &field, &cameras, 1, device)?;
    progress.inc(1);
    let (ref_colors, ref_depths) = stacked(&reference);
    let all_pixels = vec![true; ref_depths.len()];
    let max_depth = reference_config.sampler.max_depth;
    let analytic = scene.against_analytic().then(|| {
        let mut image = AnalyticImage::default();
        for cam in &cameras {
            image.extend(analytic_image(&volume, cam, (size, size), max_depth));
        }
        let clear: Vec<bool> = image
            .clearance
            .iter()
            .map(|c| *c == 0.0 || *c > GRAZING_BETAS * beta)
            .collect();
        (image, clear)
    });
    let mut rows = Vec::new();
    for &n in &sizes.box_pts {
        let config = render(n).config()?;
        let (frames, seconds) = timed_frames(&config, &field, &cameras, sizes.repeats, device)?;
        let (colors, depths): (Vec<f32>, Vec<f32>) = (
            frames.iter().flat_map(|f| f.color.data.clone()).collect(),
            frames.iter().flat_map(|f| f.depth.clone()).collect(),
        );
        rows.push(BoxRow {
            n_pts: n,
            seconds_per_frame: seconds,
            vs_reference: image_error(
                &colors,
                &ref_colors,
                &depths,
                &ref_depths,
                &all_pixels,
                &all_pixels,
            ),
            vs_analytic: analytic.as_ref().map(|(a, _)| {
                image_error(&colors, &a.colors, &depths, &a.depths, &all_pixels, &a.hits)
            }),
            vs_analytic_clear: analytic.as_ref().map(|(a, clear)| {
                image_error(&colors, &a.colors, &depths, &a.depths, clear, &a.hits)
            }),
            grazing_pixels: analytic
                .as_ref()
                .map_or(0, |(_, clear)| clear.iter().filter(|c| !**c).count()),
        });
        progress.inc(1);
    }
    Ok(BoxStudy {
        beta,
        reference_pts: sizes.box_reference_pts,
        rows,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hard_box_render_approaches_the_analytic_surface() {
        // 32×32, one view: the depth error against the analytic hit shrinks with the spacing.
        let sizes = Sizes {
            box_size: 32,
            box_pts: vec![16, 256],
            box_reference_pts: 512,
            box_views: vec![3],
            ..Sizes::new(true, None)
        };
        let bar = nerf::io::progress::Progress::hidden();
        let study = box_study(BoxScene::Hard, &sizes, &Device::Cpu, &bar).unwrap();
        let errs: Vec<ImageError> = study.rows.iter().map(|r| r.vs_analytic.unwrap()).collect();
        assert!(
            errs[0].depth_pixels > 100,
            "the box covers part of the image"
        );
        // Spacing 5/16 = 0.31 and 5/256 = 0.02: at 256 samples the mean error is below one
        // spacing, and far below the error at 16 (where thin parts are missed altogether).
        assert!(errs[1].depth_mae < 5.0 / 256.0, "{}", errs[1].depth_mae);
        assert!(errs[1].depth_mae < errs[0].depth_mae / 8.0);
        assert!(errs[1].color_rmse < errs[0].color_rmse);
    }

    #[test]
    fn a_box_render_is_the_box_config_with_its_settings() {
        // The same config as the overrides of each setting give.
        let render = BoxRender {
            beta: HARD_BETA,
            size: 48,
            n_pts: 96,
        };
        let overridden = Config::load(
            "box",
            &[
                format!("implicit_function.beta.val={HARD_BETA}"),
                "data.image_size=[48,48]".to_string(),
                "sampler.n_pts_per_ray=96".to_string(),
            ],
        )
        .unwrap();
        assert_eq!(render.config().unwrap(), overridden);
        let bad = BoxRender { n_pts: 0, ..render };
        assert!(format!("{:#}", bad.config().unwrap_err()).contains("sampler.n_pts_per_ray"));
    }
}
