//! A small point-cloud splatter for the homework's `point_vis.png`.
//!
//! The homework renders the sample points with pytorch3d's points renderer: an
//! `FoVPerspectiveCameras` (60°) at `look_at_view_transform(dist=10, elev=10, azim=96)`, points
//! of NDC radius 0.01 and colour 0.5·(0.7, 0.7, 1) on black, alpha-composited with
//! `α = 1 − d²/r²`. All points share one colour, so the composite is order-independent:
//! `colour · (1 − Π(1 − α))`.

use anyhow::Result;
use glam::DVec3;

use crate::camera::{
    camera_position_from_spherical_angles, look_at_view_transform, PerspectiveCamera,
};
use crate::images::RgbImage;

/// Settings of the point view.
#[derive(Debug, Clone, Copy)]
pub struct PointView {
    pub camera: PerspectiveCamera,
    /// Splat radius in NDC units.
    pub radius: f64,
    pub color: [f32; 3],
}

impl Default for PointView {
    fn default() -> Self {
        let eye = camera_position_from_spherical_angles(10.0, 10.0, 96.0);
        let (r, t) = look_at_view_transform(eye, DVec3::ZERO, DVec3::Y);
        // FoV 60°: NDC focal = 1 / tan(30°).
        let focal = 1.0 / (30f64.to_radians()).tan();
        Self {
            camera: PerspectiveCamera::new(r, t, focal),
            radius: 0.01,
            color: [0.35, 0.35, 0.5],
        }
    }
}

/// Splats points (`P × 3` world positions, flattened) into a `size × size` image.
pub fn render_points(points: &[f32], size: usize, view: &PointView) -> Result<RgbImage> {
    let mut log_clear = vec![0f64; size * size];
    let r = view.radius;
    let half_px = size as f64 / 2.0;
    for p in points.chunks_exact(3) {
        let q = view
            .camera
            .project(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
        if q.z.is_nan() || q.z <= 1e-3 || !q.x.is_finite() || !q.y.is_finite() {
            continue;
        }
        // Pixel centre (i, j) sits at NDC x = 1 − (2j + 1)/W, y = 1 − (2i + 1)/H.
        let col = (1.0 - q.x) * half_px - 0.5;
        let row = (1.0 - q.y) * half_px - 0.5;
        let reach = r * half_px;
        let (j0, j1) = (
            (col - reach).ceil().max(0.0),
            (col + reach).floor().min(size as f64 - 1.0),
        );
        let (i0, i1) = (
            (row - reach).ceil().max(0.0),
            (row + reach).floor().min(size as f64 - 1.0),
        );
        if j0 > j1 || i0 > i1 {
            continue;
        }
        for i in i0 as usize..=i1 as usize {
            for j in j0 as usize..=j1 as usize {
                let dx = (1.0 - (2 * j + 1) as f64 / size as f64) - q.x;
                let dy = (1.0 - (2 * i + 1) as f64 / size as f64) - q.y;
                let alpha = 1.0 - (dx * dx + dy * dy) / (r * r);
                if alpha > 0.0 {
                    log_clear[i * size + j] += (1.0 - alpha).max(1e-12).ln();
                }
            }
        }
    }
    let mut data = Vec::with_capacity(size * size * 3);
    for l in log_clear {
        let coverage = 1.0 - l.exp();
        data.extend(view.color.map(|c| c * coverage as f32));
    }
    RgbImage::new(size, size, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn origin_lands_in_the_centre_and_far_points_are_dropped() {
        let img = render_points(
            &[0.0, 0.0, 0.0],
            64,
            &PointView {
                radius: 0.05,
                ..Default::default()
            },
        )
        .unwrap();
        let centre = (32 * 64 + 32) * 3;
        assert!(img.data[centre + 2] > 0.0);
        assert_eq!(img.data[0], 0.0);
        // A point behind the camera draws nothing.
        let eye = PointView::default().camera.center();
        let behind = eye * 2.0;
        let img = render_points(
            &[behind.x as f32, behind.y as f32, behind.z as f32],
            32,
            &PointView::default(),
        )
        .unwrap();
        assert!(img.data.iter().all(|&v| v == 0.0));
    }
}
