//! How the report times and scores renders: the fastest of repeated renders, colour and depth
//! error against reference values, the analytic image of a hard SDF surface, and the observed
//! convergence order.

use anyhow::Result;
use candle_core::Device;
use serde::Serialize;

use crate::timing::{fastest, time_runs};
use nerf::config::Config;
use nerf::core::camera::PerspectiveCamera;
use nerf::core::metrics::psnr_from_mse;
use nerf::render::field::Field;
use nerf::render::view::{render_view, RenderedView};

/// Colour and depth error of a set of frames against reference values.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ImageError {
    /// Root-mean-square colour difference over all pixels and channels.
    pub color_rmse: f64,
    /// `−10·log10(MSE)` of the colour (images in [0, 1]).
    pub psnr: f64,
    /// Mean absolute depth difference over the pixels compared.
    pub depth_mae: f64,
    /// Pixels whose depth was compared.
    pub depth_pixels: usize,
}

/// Colour RMSE/PSNR over the pixels where `color_mask` is true, depth MAE over those where
/// `depth_mask` is true.
///
/// `colors`, `reference_colors`: `(P·3)`; `depths`, `reference_depths`, the masks: `(P)`.
pub fn image_error(
    colors: &[f32],
    reference_colors: &[f64],
    depths: &[f32],
    reference_depths: &[f64],
    color_mask: &[bool],
    depth_mask: &[bool],
) -> ImageError {
    let (sq, values) = colors
        .chunks_exact(3)
        .zip(reference_colors.chunks_exact(3))
        .zip(color_mask)
        .filter(|(_, m)| **m)
        .fold((0f64, 0usize), |(s, c), ((a, b), _)| {
            let d: f64 = a.iter().zip(b).map(|(a, b)| (*a as f64 - b).powi(2)).sum();
            (s + d, c + 3)
        });
    let mse = sq / values.max(1) as f64;
    let (sum, count) = depths
        .iter()
        .zip(reference_depths)
        .zip(depth_mask)
        .filter(|(_, m)| **m)
        .fold((0f64, 0usize), |(s, c), ((a, b), _)| {
            (s + (*a as f64 - b).abs(), c + 1)
        });
    ImageError {
        color_rmse: mse.sqrt(),
        psnr: psnr_from_mse(mse),
        depth_mae: if count > 0 {
            sum / count as f64
        } else {
            f64::NAN
        },
        depth_pixels: count,
    }
}

/// Renders `cameras` `repeats` times each; the frames of the last run and the mean over views
/// of each view's fastest time.
pub(super) fn timed_frames(
    config: &Config,
    field: &dyn Field,
    cameras: &[PerspectiveCamera],
    repeats: usize,
    device: &Device,
) -> Result<(Vec<RenderedView>, f64)> {
    let render = config.render_settings()?;
    let mut frames = Vec::with_capacity(cameras.len());
    let mut total = 0.0;
    for camera in cameras {
        let (runs, frame) = time_runs(repeats, || {
            render_view(
                &render.with(field),
                &nerf::Camera::from(*camera),
                config.image_size(),
                device,
            )
        })?;
        frames.push(frame);
        total += fastest(&runs);
    }
    Ok((frames, total / cameras.len().max(1) as f64))
}

/// Concatenated colours and depths of frames, as f64.
pub(super) fn stacked(frames: &[RenderedView]) -> (Vec<f64>, Vec<f64>) {
    (
        frames
            .iter()
            .flat_map(|f| f.color.data.iter().map(|v| *v as f64))
            .collect(),
        frames
            .iter()
            .flat_map(|f| f.depth.iter().map(|v| *v as f64))
            .collect(),
    )
}

/// The analytic image of an SDF volume with a hard surface.
#[derive(Debug, Clone, Default)]
pub struct AnalyticImage {
    /// `(P·3)`: the colour at the first hit, 0 on a miss.
    pub colors: Vec<f64>,
    /// `(P)`: the hit distance, 0 on a miss.
    pub depths: Vec<f64>,
    /// `(P)`: whether the ray hits.
    pub hits: Vec<bool>,
    /// `(P)`: how close the ray comes to the surface within the sampled depths (0 on a hit).
    pub clearance: Vec<f64>,
}

impl AnalyticImage {
    /// Appends `other`'s pixels after these.
    pub(super) fn extend(&mut self, other: AnalyticImage) {
        self.colors.extend(other.colors);
        self.depths.extend(other.depths);
        self.hits.extend(other.hits);
        self.clearance.extend(other.clearance);
    }
}

/// [`AnalyticImage`] of `volume` seen by `camera`, rays sampled up to `max_depth`.
pub fn analytic_image(
    volume: &nerf::core::sdf::SdfVolume,
    camera: &PerspectiveCamera,
    (width, height): (usize, usize),
    max_depth: f64,
) -> AnalyticImage {
    let mut image = AnalyticImage::default();
    for [x, y] in nerf::core::rays::pixel_grid_values(width, height) {
        let (o, d) = nerf::core::rays::ray_through_ndc(&nerf::Camera::from(*camera), x, y);
        match nerf::eval::reference::analytic_hit(&volume.sdf, o, d) {
            Some(t) => {
                image
                    .colors
                    .extend(nerf::eval::reference::surface_color(volume, o + d * t));
                image.depths.push(t);
                image.hits.push(true);
                image.clearance.push(0.0);
            }
            None => {
                image.colors.extend([0.0; 3]);
                image.depths.push(0.0);
                image.hits.push(false);
                image
                    .clearance
                    .push(nerf::eval::reference::closest_approach(
                        &volume.sdf,
                        o,
                        d,
                        max_depth,
                    ));
            }
        }
    }
    image
}

/// Misses that pass closer than this many β to the surface are "grazing": there a sample's
/// density is up to ½ whatever the spacing, so with the homework's σ = −ln(1 − density)/Δ
/// such rays turn opaque as samples are added instead of converging to a miss. At 20β the
/// density is below 1e-9.
pub const GRAZING_BETAS: f64 = 20.0;

/// Least-squares slope of `log(error)` against `log(n)`: the observed convergence order.
pub fn log_log_slope(points: &[(f64, f64)]) -> Option<f64> {
    let pts: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_error_matches_hand_computed_values() {
        // Two pixels: colours, depths, then the colour and depth masks.
        let two_pixels = |color_mask: &[bool]| {
            image_error(
                &[0.5, 0.5, 0.5, 0.0, 0.0, 0.0],
                &[0.4, 0.5, 0.5, 0.0, 0.0, 0.3],
                &[3.0, 0.0],
                &[2.5, 9.0],
                color_mask,
                &[true, false],
            )
        };
        let e = two_pixels(&[true, true]);
        let mse: f64 = (0.1f64.powi(2) + 0.3f64.powi(2)) / 6.0;
        assert!((e.color_rmse - mse.sqrt()).abs() < 1e-7);
        assert!((e.psnr + 10.0 * mse.log10()).abs() < 1e-5);
        assert!((e.depth_mae - 0.5).abs() < 1e-12);
        assert_eq!(e.depth_pixels, 1);
        let none = image_error(&[0.0; 3], &[0.0; 3], &[1.0], &[2.0], &[true], &[false]);
        assert!(none.depth_mae.is_nan() && none.psnr.is_infinite());
        // The colour mask leaves out the second pixel.
        let first = two_pixels(&[true, false]);
        assert!((first.color_rmse - (0.01f64 / 3.0).sqrt()).abs() < 1e-7);
    }

    #[test]
    fn log_log_slope_recovers_a_power_law() {
        let pts: Vec<(f64, f64)> = [8.0, 16.0, 64.0, 1024.0]
            .iter()
            .map(|n: &f64| (*n, 3.0 * n.powf(-1.5)))
            .collect();
        assert!((log_log_slope(&pts).unwrap() + 1.5).abs() < 1e-12);
        assert!(log_log_slope(&pts[..1]).is_none());
    }
}
