//! The homework's pixel grid and camera rays as batched tensors.
//!
//! The grid is `x = −linspace(−1, 1, W)`, `y = −linspace(−1, 1, H)`, row-major, so the first
//! row is the top of the image (+Y up) and the first column its left (+X left). A ray starts at
//! the camera centre and points (unit length) at the pixel's NDC point unprojected at depth 1.

use anyhow::Result;
use candle_core::{Device, Tensor};
use glam::DVec3;
use rand::seq::index::sample;
use rand::Rng;

use crate::core::camera_model::CameraModel;

/// `linspace(start, end, n)` computed in f64 (torch's values up to one f32 rounding).
pub fn linspace(start: f64, end: f64, n: usize) -> Vec<f64> {
    (0..n).map(|i| linspace_value(start, end, n, i)).collect()
}

/// Value `i` of [`linspace`]`(start, end, n)`, alone.
pub fn linspace_value(start: f64, end: f64, n: usize, i: usize) -> f64 {
    if n < 2 {
        return start;
    }
    let step = (end - start) / (n - 1) as f64;
    // Symmetric evaluation as torch does, so the last value is exactly `end`.
    if i < n / 2 {
        start + step * i as f64
    } else {
        end - step * (n - 1 - i) as f64
    }
}

/// The homework's NDC point of pixel `(column, row)` of a `width × height` image:
/// `(−linspace(−1, 1, W)[column], −linspace(−1, 1, H)[row])`, the first row the top.
pub fn homework_ndc(column: usize, row: usize, (width, height): (usize, usize)) -> [f64; 2] {
    [
        -linspace_value(-1.0, 1.0, width, column),
        -linspace_value(-1.0, 1.0, height, row),
    ]
}

/// NDC coordinates of every pixel of a `width × height` image, row-major, as `(x, y)` pairs.
pub fn pixel_grid_values(width: usize, height: usize) -> Vec<[f64; 2]> {
    let xs = linspace(-1.0, 1.0, width);
    let ys = linspace(-1.0, 1.0, height);
    let mut grid = Vec::with_capacity(width * height);
    for y in &ys {
        for x in &xs {
            grid.push([-x, -y]);
        }
    }
    grid
}

/// The pixel grid as a tensor.
///
/// Returns `(W·H, 2)` f32: NDC `(x, y)` of each pixel, row-major from the top-left pixel.
pub fn pixel_grid(width: usize, height: usize, device: &Device) -> Result<Tensor> {
    let flat: Vec<f32> = pixel_grid_values(width, height)
        .into_iter()
        .flat_map(|[x, y]| [x as f32, y as f32])
        .collect();
    Ok(Tensor::from_vec(flat, (width * height, 2), device)?)
}

/// `n` distinct pixel indices (row-major, `y·W + x`) drawn uniformly from a `width × height`
/// image, for training batches. `n` larger than the image takes every pixel once.
pub fn random_pixel_indices(
    width: usize,
    height: usize,
    n: usize,
    rng: &mut impl Rng,
) -> Vec<usize> {
    let total = width * height;
    sample(rng, total, n.min(total)).into_vec()
}

/// Origin and unit direction of the ray through NDC point `(x, y)` of any camera kind
/// ([`CameraModel::ray_through_ndc`]).
pub fn ray_through_ndc(camera: &dyn CameraModel, x: f64, y: f64) -> (DVec3, DVec3) {
    camera.ray_through_ndc(x, y)
}

/// A batch of rays.
#[derive(Debug, Clone)]
pub struct Rays {
    /// `(N, 3)` f32 ray origins (the camera centre).
    pub origins: Tensor,
    /// `(N, 3)` f32 unit directions.
    pub directions: Tensor,
}

impl Rays {
    /// Rays through the given NDC points.
    ///
    /// `ndc_points`: N points `(x, y)`; returns origins and directions of shape `(N, 3)`.
    pub fn from_ndc_points(
        camera: &dyn CameraModel,
        ndc_points: &[[f64; 2]],
        device: &Device,
    ) -> Result<Self> {
        let n = ndc_points.len();
        let mut origins = Vec::with_capacity(3 * n);
        let mut directions = Vec::with_capacity(3 * n);
        for &[x, y] in ndc_points {
            let (o, d) = ray_through_ndc(camera, x, y);
            origins.extend(o.to_array().map(|v| v as f32));
            directions.extend(d.to_array().map(|v| v as f32));
        }
        Ok(Self {
            origins: Tensor::from_vec(origins, (n, 3), device)?,
            directions: Tensor::from_vec(directions, (n, 3), device)?,
        })
    }

    /// One ray per pixel of a `width × height` image, row-major: `(W·H, 3)` origins and directions.
    pub fn for_image(
        camera: &dyn CameraModel,
        width: usize,
        height: usize,
        device: &Device,
    ) -> Result<Self> {
        Self::for_pixel_range(camera, (width, height), 0..width * height, device)
    }

    /// Rays through the pixels with the given row-major indices: `(len(indices), 3)`, each
    /// [`CameraModel::pixel_ray`].
    pub fn for_pixels(
        camera: &dyn CameraModel,
        width: usize,
        height: usize,
        indices: &[usize],
        device: &Device,
    ) -> Result<Self> {
        Self::from_pixels(camera, (width, height), indices.iter().copied(), device)
    }

    /// Rays through the row-major pixels `pixels` of a `width × height` image:
    /// `(len, 3)` rows of [`Rays::for_image`].
    pub fn for_pixel_range(
        camera: &dyn CameraModel,
        size: (usize, usize),
        pixels: std::ops::Range<usize>,
        device: &Device,
    ) -> Result<Self> {
        Self::from_pixels(camera, size, pixels, device)
    }

    fn from_pixels(
        camera: &dyn CameraModel,
        (width, height): (usize, usize),
        pixels: impl ExactSizeIterator<Item = usize>,
        device: &Device,
    ) -> Result<Self> {
        let n = pixels.len();
        let mut origins = Vec::with_capacity(3 * n);
        let mut directions = Vec::with_capacity(3 * n);
        for i in pixels {
            let (o, d) = camera.pixel_ray(i % width, i / width, (width, height));
            origins.extend(o.to_array().map(|v| v as f32));
            directions.extend(d.to_array().map(|v| v as f32));
        }
        Ok(Self {
            origins: Tensor::from_vec(origins, (n, 3), device)?,
            directions: Tensor::from_vec(directions, (n, 3), device)?,
        })
    }

    /// The same rays in `dtype` (float64 for gradient checks: the renderer then works in
    /// float64 through the generic tensor ops).
    pub fn to_dtype(&self, dtype: candle_core::DType) -> Result<Self> {
        Ok(Self {
            origins: self.origins.to_dtype(dtype)?,
            directions: self.directions.to_dtype(dtype)?,
        })
    }

    /// Number of rays N.
    pub fn len(&self) -> usize {
        self.origins.dims()[0]
    }

    /// True when the batch holds no ray.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Rays `start .. start + len` of the batch.
    pub fn narrow(&self, start: usize, len: usize) -> Result<Self> {
        Ok(Self {
            origins: self.origins.narrow(0, start, len)?,
            directions: self.directions.narrow(0, start, len)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::camera::surround_cameras;

    #[test]
    fn linspace_matches_endpoints() {
        let v = linspace(-1.0, 1.0, 5);
        assert_eq!(v, vec![-1.0, -0.5, 0.0, 0.5, 1.0]);
        assert_eq!(linspace(2.0, 6.0, 1), vec![2.0]);
        assert_eq!(*linspace(0.0, 5.0, 64).last().unwrap(), 5.0);
    }

    #[test]
    fn grid_shape_and_orientation() {
        let (w, h) = (7, 4);
        let g = pixel_grid(w, h, &Device::Cpu).unwrap();
        assert_eq!(g.dims(), &[w * h, 2]);
        let v = g.to_vec2::<f32>().unwrap();
        // Top-left pixel is (+1, +1): +X left, +Y up.
        assert_eq!(v[0], vec![1.0, 1.0]);
        // Last pixel of the first row is the right edge.
        assert_eq!(v[w - 1], vec![-1.0, 1.0]);
        // Bottom-right pixel.
        assert_eq!(v[w * h - 1], vec![-1.0, -1.0]);
    }

    #[test]
    fn rays_have_unit_directions_and_shapes() {
        let cam = surround_cameras(3.0, 20, DVec3::Y, 1.0)[4];
        for (w, h) in [(5, 3), (16, 16), (20, 15)] {
            let rays = Rays::for_image(&cam, w, h, &Device::Cpu).unwrap();
            assert_eq!(rays.origins.dims(), &[w * h, 3]);
            assert_eq!(rays.directions.dims(), &[w * h, 3]);
            let norms = rays
                .directions
                .sqr()
                .unwrap()
                .sum(1)
                .unwrap()
                .sqrt()
                .unwrap();
            for n in norms.to_vec1::<f32>().unwrap() {
                assert!((n - 1.0).abs() < 1e-6, "norm {n}");
            }
        }
    }

    #[test]
    fn central_ray_points_at_the_origin() {
        let cam = surround_cameras(3.0, 20, DVec3::Y, 1.0)[7];
        let (o, d) = ray_through_ndc(&cam, 0.0, 0.0);
        // The camera looks at the origin, so o + 3·d = 0.
        assert!((o + d * 3.0).length() < 1e-12);
    }

    #[test]
    fn corner_ray_matches_the_focal_length() {
        // In view space the corner ray of a focal-1 camera is (1, 1, 1)/√3.
        let cam = surround_cameras(3.0, 20, DVec3::Y, 1.0)[0];
        let (_, d) = ray_through_ndc(&cam, 1.0, 1.0);
        let view = cam.world_to_view(d) - cam.world_to_view(DVec3::ZERO);
        let expected = DVec3::splat(1.0 / 3f64.sqrt());
        assert!((view - expected).length() < 1e-12);
    }

    #[test]
    fn pixel_subsets_match_the_full_grid() {
        let cam = surround_cameras(3.0, 20, DVec3::Y, 1.0)[2];
        let (w, h) = (9, 6);
        let all = Rays::for_image(&cam, w, h, &Device::Cpu).unwrap();
        let mut rng = rand::rng();
        let idx = random_pixel_indices(w, h, 10, &mut rng);
        assert_eq!(idx.len(), 10);
        let sub = Rays::for_pixels(&cam, w, h, &idx, &Device::Cpu).unwrap();
        let all_d = all.directions.to_vec2::<f32>().unwrap();
        let sub_d = sub.directions.to_vec2::<f32>().unwrap();
        for (k, &i) in idx.iter().enumerate() {
            assert_eq!(all_d[i], sub_d[k]);
        }
        // Asking for more pixels than exist takes each once.
        let mut every = random_pixel_indices(w, h, 1000, &mut rng);
        every.sort();
        assert_eq!(every, (0..w * h).collect::<Vec<_>>());
    }
}
