//! Point clouds from rendered views, as nerfstudio's `ns-export pointcloud` makes them: each
//! ray that the field makes opaque enough gives one point at its expected depth, with its
//! colour.

use anyhow::Result;
use candle_core::Device;

use nerf::core::camera::Camera;
use nerf::core::rays::Rays;
use nerf::render::bands::{band_rays, pixel_bands};
use nerf::render::renderer::{RenderOutput, VolumeRenderer, BLACK};
use nerf::render::view::Pipeline;

/// Coloured points in world space.
#[derive(Debug, Clone, Default)]
pub struct ColoredPoints {
    /// Positions.
    pub points: Vec<[f32; 3]>,
    /// RGB colours in `[0, 1]`, one per point.
    pub colors: Vec<[f32; 3]>,
}

/// The points one view sees: for each pixel's ray whose opacity `Σ wᵢ` exceeds
/// `min_opacity`, the point `origin + direction · Σ wᵢtᵢ / Σ wᵢ` (nerfstudio's expected depth,
/// normalised by the accumulated weight) with the colour `Σ wᵢcᵢ / Σ wᵢ`. The rays are made and
/// rendered about `band` at a time (whole renderer chunks, so the points do not depend on it).
pub fn depth_points(
    pipeline: &Pipeline,
    camera: &Camera,
    size: (usize, usize),
    min_opacity: f32,
    band: usize,
    device: &Device,
) -> Result<ColoredPoints> {
    camera.validate()?;
    // On black, so that dividing by the opacity recovers the colour.
    let black = VolumeRenderer {
        background: BLACK,
        ..*pipeline.renderer
    };
    let black = Pipeline {
        renderer: &black,
        ..*pipeline
    };
    let band = black.rays_per_band(band);
    let mut cloud = ColoredPoints::default();
    for pixels in pixel_bands(size.0 * size.1, band) {
        let rays = band_rays(camera, size, pixels, device)?;
        let out = black.render(&rays)?;
        add_opaque_points(&mut cloud, &rays, &out, min_opacity)?;
    }
    Ok(cloud)
}

/// Adds to `cloud` the point and colour of every ray of `rays` whose opacity in `out` exceeds
/// `min_opacity`.
fn add_opaque_points(
    cloud: &mut ColoredPoints,
    rays: &Rays,
    out: &RenderOutput,
    min_opacity: f32,
) -> Result<()> {
    let origins = rays.origins.flatten_all()?.to_vec1::<f32>()?;
    let directions = rays.directions.flatten_all()?.to_vec1::<f32>()?;
    let color = out.color.flatten_all()?.to_vec1::<f32>()?;
    let depth = out.depth.flatten_all()?.to_vec1::<f32>()?;
    let opacity = out.opacity.flatten_all()?.to_vec1::<f32>()?;
    for (i, &a) in opacity.iter().enumerate() {
        // Also skips a NaN opacity (the renderer refuses NaN colour and depth already).
        if a.is_nan() || a <= min_opacity.max(0.0) {
            continue;
        }
        let t = depth[i] / a;
        cloud
            .points
            .push([0, 1, 2].map(|k| origins[3 * i + k] + t * directions[3 * i + k]));
        cloud
            .colors
            .push([0, 1, 2].map(|k| (color[3 * i + k] / a).clamp(0.0, 1.0)));
    }
    Ok(())
}
