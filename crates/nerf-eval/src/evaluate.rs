//! `nerf eval`: PSNR and SSIM of a trained NeRF against a split of the dataset.

use std::path::Path;

use anyhow::Result;
use candle_core::Device;
use serde::Serialize;

use nerf_core::metrics::{mean, psnr, psnr_over, ssim, SSIM_WINDOW};
use nerf_files::images::write_png;
use nerf_files::output::prepare_out_dir;
use nerf_files::progress::progress_bar;
use nerf_render::skipping::SampleCounts;
use nerf_render::view::{render_view, Pipeline};
use nerf_scene::dataset::{Dataset, Split};

/// PSNR and SSIM of one view.
#[derive(Debug, Clone, Serialize)]
pub struct ViewScore {
    /// Frame name, e.g. `r_0`.
    pub frame: String,
    /// PSNR in dB of the rendered colour against the ground-truth image, over the pixels its
    /// mask uses when the frame has one.
    pub psnr: f64,
    /// SSIM of the rendered colour against the ground-truth image
    /// ([`nerf_core::metrics::ssim`]: 11×11 Gaussian window, data range 1), over the whole
    /// image even when the frame has a mask; `None` (JSON
    /// `null`) for images under 11 pixels on a side, where SSIM's window does not fit.
    pub ssim: Option<f64>,
}

/// PSNR over a split (mean, min, max and per view) and mean SSIM.
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    /// The split evaluated (`train`, `val` or `test`).
    pub split: String,
    /// Render width in pixels.
    pub width: usize,
    /// Render height in pixels.
    pub height: usize,
    /// Samples per ray.
    pub n_pts_per_ray: usize,
    /// The colour prediction and ground truth were composited on (RGB in [0, 1]).
    pub background: [f32; 3],
    /// Mean seconds to render one view.
    pub seconds_per_view: f64,
    /// Fraction of drawn samples at which the field was evaluated (1 when dense).
    pub evaluated_fraction: f64,
    /// Mean PSNR over the views, in dB.
    pub mean_psnr: f64,
    /// Lowest PSNR of a view, in dB.
    pub min_psnr: f64,
    /// Highest PSNR of a view, in dB.
    pub max_psnr: f64,
    /// Mean SSIM over the views (`None` for images under 11 pixels on a side).
    pub mean_ssim: Option<f64>,
    /// Every view's score, in dataset order.
    pub views: Vec<ViewScore>,
}

impl EvalReport {
    /// One line: split, views, size, background, PSNR mean/min/max, mean SSIM, time per view,
    /// evaluated fraction.
    pub fn summary(&self) -> String {
        format!(
            "{} split, {} {} at {}x{}, {} points, on {}: PSNR mean {:.2} dB, min {:.2}, max {:.2}; SSIM mean {}; {:.3} s per view, field evaluated at {:.1}% of samples",
            self.split,
            self.views.len(),
            if self.views.len() == 1 { "view" } else { "views" },
            self.width,
            self.height,
            self.n_pts_per_ray,
            nerf_core::image::colour_name(self.background),
            self.mean_psnr,
            self.min_psnr,
            self.max_psnr,
            self.mean_ssim
                .map_or_else(|| "n/a (images under 11 pixels)".to_string(), |v| format!("{v:.4}")),
            self.seconds_per_view,
            100.0 * self.evaluated_fraction
        )
    }
}

/// Whether SSIM's 11×11 window fits an image of `(width, height)`.
fn ssim_fits(size: (usize, usize)) -> bool {
    size.0 >= SSIM_WINDOW && size.1 >= SSIM_WINDOW
}

/// Renders every view of `dataset` through `pipeline` and scores it (PSNR over the pixels a
/// frame's mask uses, SSIM over the whole image); with `save_images`, writes each whole
/// prediction as `<frame>.png` there. `limit` evaluates only the first views.
pub fn evaluate(
    pipeline: &Pipeline,
    dataset: &Dataset,
    split: Split,
    save_images: Option<&Path>,
    limit: Option<usize>,
    device: &Device,
) -> Result<EvalReport> {
    let size = (dataset.width, dataset.height);
    if let Some(dir) = save_images {
        prepare_out_dir(dir)?;
    }
    let n = limit.map_or(dataset.frames.len(), |l| l.min(dataset.frames.len()));
    let bar = progress_bar(n as u64, "evaluating");
    let mut views = Vec::with_capacity(n);
    let mut render_seconds = 0.0;
    let mut counts = SampleCounts::default();
    for (index, (frame, truth)) in dataset
        .frames
        .iter()
        .zip(&dataset.images)
        .enumerate()
        .take(n)
    {
        let t = std::time::Instant::now();
        let predicted = render_view(pipeline, &frame.camera, size, device)?;
        render_seconds += t.elapsed().as_secs_f64();
        counts = counts + predicted.samples;
        let name = frame
            .file_path
            .file_stem()
            .map_or_else(|| "view".to_string(), |s| s.to_string_lossy().to_string());
        if let Some(dir) = save_images {
            write_png(&dir.join(format!("{name}.png")), &predicted.color)?;
        }
        views.push(ViewScore {
            frame: name,
            psnr: match dataset.mask(index) {
                Some(mask) => psnr_over(&predicted.color, truth, mask.used()),
                None => psnr(&predicted.color, truth),
            },
            ssim: ssim_fits(size)
                .then(|| ssim(&predicted.color, truth))
                .transpose()?,
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    let values: Vec<f64> = views.iter().map(|v| v.psnr).collect();
    Ok(EvalReport {
        split: split.name().to_string(),
        width: size.0,
        height: size.1,
        n_pts_per_ray: pipeline.sampler.samples_per_ray(),
        background: pipeline.renderer.background,
        seconds_per_view: render_seconds / n.max(1) as f64,
        evaluated_fraction: counts.evaluated_fraction(),
        mean_psnr: mean(&values),
        min_psnr: values.iter().cloned().fold(f64::INFINITY, f64::min),
        max_psnr: values.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
        mean_ssim: ssim_fits(size)
            .then(|| mean(&views.iter().filter_map(|v| v.ssim).collect::<Vec<_>>())),
        views,
    })
}
