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

use crate::camera::Camera;
pub use crate::pixel_grid::{
    homework_ndc, linspace, linspace_value, pixel_grid, pixel_grid_values,
};

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
/// ([`Camera::ray_through_ndc`]).
pub fn ray_through_ndc(camera: &Camera, x: f64, y: f64) -> (DVec3, DVec3) {
    camera.ray_through_ndc(x, y)
}

/// A batch of rays.
#[derive(Debug, Clone)]
pub struct Rays {
    /// `(N, 3)` f32 ray origins (the camera centre).
    pub origins: Tensor,
    /// `(N, 3)` f32 unit directions.
    pub directions: Tensor,
    /// `(N,)` u32: the training camera (image) each ray comes from, for fields with parts
    /// learnt per image (appearance); `None` for rays of any other camera.
    pub camera_index: Option<Tensor>,
}

impl Rays {
    /// Rays from `origins` and unit `directions`, both `(N, 3)`, of no training camera.
    pub fn new(origins: Tensor, directions: Tensor) -> Self {
        Self {
            origins,
            directions,
            camera_index: None,
        }
    }

    /// One ray per pixel of a `width × height` image, row-major: `(W·H, 3)` origins and directions.
    pub fn for_image(
        camera: &Camera,
        width: usize,
        height: usize,
        device: &Device,
    ) -> Result<Self> {
        Self::for_pixel_range(camera, (width, height), 0..width * height, device)
    }

    /// Rays through the pixels with the given row-major indices: `(len(indices), 3)`, each
    /// [`Camera::pixel_ray`].
    pub fn for_pixels(
        camera: &Camera,
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
        camera: &Camera,
        size: (usize, usize),
        pixels: std::ops::Range<usize>,
        device: &Device,
    ) -> Result<Self> {
        Self::from_pixels(camera, size, pixels, device)
    }

    fn from_pixels(
        camera: &Camera,
        (width, height): (usize, usize),
        pixels: impl ExactSizeIterator<Item = usize>,
        device: &Device,
    ) -> Result<Self> {
        let rays = pixels.map(|i| camera.pixel_ray(i % width, i / width, (width, height)));
        Self::from_f64_rays(rays, device)
    }

    /// Rays of no training camera from `(origin, unit direction)` pairs in f64: `(N, 3)` f32
    /// origins and directions on `device`.
    fn from_f64_rays(
        rays: impl ExactSizeIterator<Item = (DVec3, DVec3)>,
        device: &Device,
    ) -> Result<Self> {
        let n = rays.len();
        let mut origins = Vec::with_capacity(3 * n);
        let mut directions = Vec::with_capacity(3 * n);
        for (o, d) in rays {
            origins.extend(o.to_array().map(|v| v as f32));
            directions.extend(d.to_array().map(|v| v as f32));
        }
        Ok(Self::new(
            Tensor::from_vec(origins, (n, 3), device)?,
            Tensor::from_vec(directions, (n, 3), device)?,
        ))
    }

    /// The same rays in `dtype` (float64 for gradient checks: the renderer then works in
    /// float64 through the generic tensor ops).
    pub fn to_dtype(&self, dtype: candle_core::DType) -> Result<Self> {
        Ok(Self {
            origins: self.origins.to_dtype(dtype)?,
            directions: self.directions.to_dtype(dtype)?,
            camera_index: self.camera_index.clone(),
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
            camera_index: match &self.camera_index {
                Some(c) => Some(c.narrow(0, start, len)?),
                None => None,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::surround_cameras;

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
            let rays = Rays::for_image(&Camera::from(cam), w, h, &Device::Cpu).unwrap();
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
        let (o, d) = ray_through_ndc(&Camera::from(cam), 0.0, 0.0);
        // The camera looks at the origin, so o + 3·d = 0.
        assert!((o + d * 3.0).length() < 1e-12);
    }

    #[test]
    fn corner_ray_matches_the_focal_length() {
        // In view space the corner ray of a focal-1 camera is (1, 1, 1)/√3.
        let cam = surround_cameras(3.0, 20, DVec3::Y, 1.0)[0];
        let (_, d) = ray_through_ndc(&Camera::from(cam), 1.0, 1.0);
        let view = cam.world_to_view(d) - cam.world_to_view(DVec3::ZERO);
        let expected = DVec3::splat(1.0 / 3f64.sqrt());
        assert!((view - expected).length() < 1e-12);
    }

    #[test]
    fn pixel_subsets_match_the_full_grid() {
        let cam = surround_cameras(3.0, 20, DVec3::Y, 1.0)[2];
        let (w, h) = (9, 6);
        let all = Rays::for_image(&Camera::from(cam), w, h, &Device::Cpu).unwrap();
        let mut rng = rand::rng();
        let idx = random_pixel_indices(w, h, 10, &mut rng);
        assert_eq!(idx.len(), 10);
        let sub = Rays::for_pixels(&Camera::from(cam), w, h, &idx, &Device::Cpu).unwrap();
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

#[cfg(test)]
mod camera_kind_tests {
    use super::*;
    use crate::camera::surround_cameras;

    #[test]
    fn the_pinhole_kind_is_pytorch3d_unprojection() {
        let pinhole = surround_cameras(4.0, 3, DVec3::Y, 1.5)[1];
        let camera = Camera::from(pinhole);
        let (o, d) = camera.ray_through_ndc(0.3, -0.6);
        assert_eq!((o, d), ray_through_ndc(&camera, 0.3, -0.6));
        assert!((o - camera.center()).length() < 1e-12);
        let target = pinhole.unproject_ndc(0.3, -0.6, 1.0);
        assert!((d - (target - o).normalize()).length() < 1e-12);
    }
}
