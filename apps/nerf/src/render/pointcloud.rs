//! A small point-cloud splatter for the homework's `point_vis.png`.
//!
//! The homework renders the sample points with pytorch3d's points renderer: an
//! `FoVPerspectiveCameras` (60°) at `look_at_view_transform(dist=10, elev=10, azim=96)`, points
//! of NDC radius 0.01 and colour 0.5·(0.7, 0.7, 1) on black, alpha-composited with
//! `α = 1 − d²/r²`. Like pytorch3d's rasteriser (`points_per_pixel`, default 8), each pixel
//! keeps only the nearest few points in depth that cover it; where many more overlap (the
//! rays converge towards the camera) this gives the reference's ring pattern. All points share
//! one colour, so the composite of the kept points is order-independent:
//! `colour · (1 − Π(1 − α))`.

use anyhow::Result;
use glam::DVec3;
use rayon::prelude::*;

use nerf::core::camera::{
    camera_position_from_spherical_angles, look_at_view_transform, PerspectiveCamera,
};
use nerf::core::image::RgbImage;

/// Settings of the point view.
#[derive(Debug, Clone, Copy)]
pub struct PointView {
    /// The viewing camera (the homework's 60° view from distance 10).
    pub camera: PerspectiveCamera,
    /// Splat radius in NDC units.
    pub radius: f64,
    /// RGB colour of every point, in [0, 1].
    pub color: [f32; 3],
    /// Points kept per pixel, nearest in depth first (pytorch3d's `points_per_pixel`).
    pub points_per_pixel: usize,
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
            points_per_pixel: 8,
        }
    }
}

/// A projected point: its NDC position and depth, and the pixel rows and columns it covers.
#[derive(Debug, Clone, Copy)]
struct Splat {
    x: f64,
    y: f64,
    depth: f64,
    rows: (usize, usize),
    cols: (usize, usize),
}

/// Projects one point; `None` when it is behind the camera or covers no pixel.
fn project(p: &[f32], size: usize, view: &PointView) -> Option<Splat> {
    let q = view
        .camera
        .project(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
    if q.z.is_nan() || q.z <= 1e-3 || !q.x.is_finite() || !q.y.is_finite() {
        return None;
    }
    // Pixel centre (i, j) sits at NDC x = 1 − (2j + 1)/W, y = 1 − (2i + 1)/H.
    let half_px = size as f64 / 2.0;
    let col = (1.0 - q.x) * half_px - 0.5;
    let row = (1.0 - q.y) * half_px - 0.5;
    let reach = view.radius * half_px;
    let (j0, j1) = (
        (col - reach).ceil().max(0.0),
        (col + reach).floor().min(size as f64 - 1.0),
    );
    let (i0, i1) = (
        (row - reach).ceil().max(0.0),
        (row + reach).floor().min(size as f64 - 1.0),
    );
    if j0 > j1 || i0 > i1 {
        return None;
    }
    Some(Splat {
        x: q.x,
        y: q.y,
        depth: q.z,
        rows: (i0 as usize, i1 as usize),
        cols: (j0 as usize, j1 as usize),
    })
}

/// The rows `first..first + n_kept.len() / size` of the image being splatted: per pixel, the
/// (depth, α) of the nearest `k` covering points so far, how many there are, and which of
/// them is the farthest once there are `k`.
struct Band {
    first: usize,
    kept: Vec<(f64, f64)>,
    n_kept: Vec<u8>,
    far: Vec<u8>,
}

impl Band {
    /// Adds the part of `s` that falls in this band's rows; `centres[i]` is the NDC
    /// coordinate `1 − (2i + 1)/size` of pixel row or column `i`.
    fn splat(&mut self, s: &Splat, size: usize, k: usize, radius: f64, centres: &[f64]) {
        let last = self.first + self.n_kept.len() / size;
        let (i0, i1) = (
            s.rows.0.max(self.first),
            s.rows.1.min(last.saturating_sub(1)),
        );
        if s.rows.1 < self.first || s.rows.0 >= last || i0 > i1 {
            return;
        }
        for i in i0..=i1 {
            let dy = centres[i] - s.y;
            for (j, centre) in centres.iter().enumerate().take(s.cols.1 + 1).skip(s.cols.0) {
                let dx = centre - s.x;
                let alpha = 1.0 - (dx * dx + dy * dy) / (radius * radius);
                if alpha > 0.0 {
                    let pixel = (i - self.first) * size + j;
                    keep_nearest(
                        &mut self.kept[pixel * k..(pixel + 1) * k],
                        &mut self.n_kept[pixel],
                        &mut self.far[pixel],
                        (s.depth, alpha),
                    );
                }
            }
        }
    }
}

/// Points projected at a time (then splatted, each band of rows on its own thread).
const POINTS_PER_PASS: usize = 1 << 18;

#[cfg(test)]
/// Splats points (`P × 3` world positions, flattened) into a `size × size` image: a
/// [`PointSplatter`] given all of them at once.
pub(crate) fn render_points(points: &[f32], size: usize, view: &PointView) -> Result<RgbImage> {
    let mut splatter = PointSplatter::new(size, view)?;
    splatter.add(points);
    splatter.finish()
}

/// A `size × size` point image built from points given a piece at a time, so that they need
/// not all exist at once. Points are projected in parallel, and the image's row bands are
/// splatted in parallel, each taking the points in their order, so every pixel sees its points
/// in input order (as one thread would): the image depends on the points and their order, not
/// on how they were cut into pieces.
pub struct PointSplatter {
    size: usize,
    view: PointView,
    centres: Vec<f64>,
    bands: Vec<Band>,
}

impl PointSplatter {
    /// An empty image; an error when `view.points_per_pixel` is not 1 to 255.
    pub fn new(size: usize, view: &PointView) -> Result<Self> {
        anyhow::ensure!(
            view.points_per_pixel >= 1,
            "points_per_pixel must be at least 1"
        );
        anyhow::ensure!(
            view.points_per_pixel <= u8::MAX as usize,
            "points_per_pixel must be at most 255"
        );
        let k = view.points_per_pixel;
        let centres: Vec<f64> = (0..size)
            .map(|i| 1.0 - (2 * i + 1) as f64 / size as f64)
            .collect();
        let rows_per_band = size
            .div_ceil(2 * rayon::current_num_threads().max(1))
            .max(1);
        let bands: Vec<Band> = (0..size)
            .step_by(rows_per_band)
            .map(|first| {
                let rows = rows_per_band.min(size - first);
                Band {
                    first,
                    kept: vec![(0.0, 0.0); rows * size * k],
                    n_kept: vec![0; rows * size],
                    far: vec![0; rows * size],
                }
            })
            .collect();
        Ok(Self {
            size,
            view: *view,
            centres,
            bands,
        })
    }

    /// Splats the next points (`P × 3` world positions, flattened), after those already given.
    pub fn add(&mut self, points: &[f32]) {
        let (size, view) = (self.size, &self.view);
        let k = view.points_per_pixel;
        for chunk in points.chunks(3 * POINTS_PER_PASS) {
            let splats: Vec<Splat> = chunk
                .par_chunks_exact(3)
                .filter_map(|p| project(p, size, view))
                .collect();
            let centres = &self.centres;
            self.bands.par_iter_mut().for_each(|band| {
                for s in &splats {
                    band.splat(s, size, k, view.radius, centres);
                }
            });
        }
    }

    /// The image of every point given.
    pub fn finish(self) -> Result<RgbImage> {
        let (size, k) = (self.size, self.view.points_per_pixel);
        let mut data = Vec::with_capacity(size * size * 3);
        for band in &self.bands {
            for (pixel, &n) in band.n_kept.iter().enumerate() {
                let clear: f64 = band.kept[pixel * k..pixel * k + n as usize]
                    .iter()
                    .map(|&(_, alpha)| 1.0 - alpha)
                    .product();
                data.extend(self.view.color.map(|c| c * (1.0 - clear) as f32));
            }
        }
        RgbImage::new(size, size, data)
    }
}

/// Adds `point` (depth, α) to the `*n` points in `kept`, keeping the `kept.len()` nearest:
/// when full, it replaces the farthest if nearer (ties keep the earlier point, as the order
/// of the input decides in pytorch3d). `*far` caches the farthest one's index (the last of
/// equally far ones) while `kept` is full.
fn keep_nearest(kept: &mut [(f64, f64)], n: &mut u8, far: &mut u8, point: (f64, f64)) {
    let k = kept.len();
    if (*n as usize) < k {
        kept[*n as usize] = point;
        *n += 1;
        if *n as usize == k {
            *far = farthest(kept);
        }
        return;
    }
    if point.0 < kept[*far as usize].0 {
        kept[*far as usize] = point;
        *far = farthest(kept);
    }
}

/// The index of the largest depth in `kept` (the last of equal ones, as `Iterator::max_by`).
fn farthest(kept: &[(f64, f64)]) -> u8 {
    let mut best = 0;
    for (i, p) in kept.iter().enumerate().skip(1) {
        if p.0.total_cmp(&kept[best].0) != std::cmp::Ordering::Less {
            best = i;
        }
    }
    best as u8
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

    #[test]
    fn only_the_nearest_points_per_pixel_count() {
        // 20 points on the line of sight through the image centre, all with the same α at the
        // centre pixel: it composites only `points_per_pixel` of them.
        // A radius just over the centre pixel's offset, so that α ≈ 0.22 and the counts differ.
        let view = PointView {
            radius: 0.025,
            ..Default::default()
        };
        let eye = view.camera.center();
        // All in front of the camera (eye · t with t < 1).
        let points: Vec<f32> = (0..20)
            .flat_map(|i| {
                let p = eye * (0.05 * i as f64 - 0.5);
                [p.x as f32, p.y as f32, p.z as f32]
            })
            .collect();
        let size = 64;
        let q = view.camera.project(DVec3::ZERO);
        let centre = (size / 2) * size + size / 2;
        let dx = (1.0 - (2 * (size / 2) + 1) as f64 / size as f64) - q.x;
        let dy = (1.0 - (2 * (size / 2) + 1) as f64 / size as f64) - q.y;
        let alpha = 1.0 - (dx * dx + dy * dy) / (view.radius * view.radius);
        for (k, expected_count) in [(1, 1), (8, 8), (100, 20)] {
            let v = PointView {
                points_per_pixel: k,
                ..view
            };
            let img = render_points(&points, size, &v).unwrap();
            let coverage = 1.0 - (1.0 - alpha).powi(expected_count);
            let got = img.data[centre * 3 + 2] as f64 / v.color[2] as f64;
            assert!((0.1..0.3).contains(&alpha), "{alpha}");
            assert!((got - coverage).abs() < 1e-5, "k={k}: {got} vs {coverage}");
        }
        let mut kept = [(0.0, 0.0); 2];
        let (mut n, mut far) = (0, 0);
        for p in [(3.0, 0.1), (1.0, 0.2), (2.0, 0.3), (5.0, 0.4)] {
            keep_nearest(&mut kept, &mut n, &mut far, p);
        }
        assert_eq!((n, kept), (2, [(2.0, 0.3), (1.0, 0.2)]));
    }

    #[test]
    fn points_given_in_pieces_make_the_image_given_at_once() {
        // Points on a spiral through the view's centre, many covering the same pixels.
        let points: Vec<f32> = (0..3000)
            .flat_map(|i| {
                let t = i as f32 * 0.01;
                [
                    t.cos() * t * 0.05,
                    (i % 7) as f32 * 0.1 - 0.3,
                    t.sin() * t * 0.05,
                ]
            })
            .collect();
        let view = PointView {
            radius: 0.05,
            ..Default::default()
        };
        let whole = render_points(&points, 48, &view).unwrap();
        assert!(whole.data.iter().filter(|&&v| v > 0.0).count() > 100);
        for piece in [3, 3 * 7, 3 * 1000] {
            let mut splatter = PointSplatter::new(48, &view).unwrap();
            for p in points.chunks(piece) {
                splatter.add(p);
            }
            assert_eq!(splatter.finish().unwrap().data, whole.data, "piece {piece}");
        }
    }
}
