//! Stratified sampling of points along rays.

use anyhow::{ensure, Result};
use candle_core::{DType, Tensor};
use rand::Rng;

use nerf_core::rays::{linspace, Rays};

/// The depths `depths` (`S` of them) shared by every ray, as a `(1, S, 1)` tensor: f64 when
/// `dtype` is, else f32 (what a sampler's unjittered depths are for rays of that dtype).
pub(crate) fn shared_lengths(
    depths: Vec<f64>,
    dtype: DType,
    device: &candle_core::Device,
) -> Result<Tensor> {
    let s = depths.len();
    Ok(if dtype == DType::F64 {
        Tensor::from_vec(depths, (1, s, 1), device)?
    } else {
        let z: Vec<f32> = depths.into_iter().map(|v| v as f32).collect();
        Tensor::from_vec(z, (1, s, 1), device)?
    })
}
use nerf_kernels::sample_points::sample_points;

/// Sample points along a batch of rays.
#[derive(Debug, Clone)]
pub struct RaySamples {
    /// `(N, S, 3)` f32 world positions `origin + t·direction`.
    pub points: Tensor,
    /// `(N, S, 1)` f32 distances `t` along each ray, increasing.
    pub lengths: Tensor,
}

/// The homework's `StratifiedRaysampler`: `n_pts_per_ray` depths `linspace(min_depth,
/// max_depth, n)`, optionally jittered inside their bins for training.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StratifiedSampler {
    /// Samples per ray `S` (`sampler.n_pts_per_ray`, at least 1).
    pub n_pts_per_ray: usize,
    /// Depth of the first sample along each ray (`sampler.min_depth`, ≥ 0).
    pub min_depth: f64,
    /// Depth of the last sample along each ray (`sampler.max_depth`, ≥ `min_depth`).
    pub max_depth: f64,
}

impl StratifiedSampler {
    /// `n_pts_per_ray` (≥ 1) samples per ray between `min_depth` and `max_depth`
    /// (finite, 0 ≤ min ≤ max).
    pub fn new(n_pts_per_ray: usize, min_depth: f64, max_depth: f64) -> Result<Self> {
        ensure!(
            n_pts_per_ray >= 1,
            "sampler.n_pts_per_ray must be at least 1"
        );
        ensure!(
            min_depth.is_finite() && max_depth.is_finite(),
            "sampler.min_depth and sampler.max_depth must be finite"
        );
        ensure!(min_depth >= 0.0, "sampler.min_depth must be non-negative");
        ensure!(
            min_depth <= max_depth,
            "sampler.min_depth must not exceed sampler.max_depth"
        );
        Ok(Self {
            n_pts_per_ray,
            min_depth,
            max_depth,
        })
    }

    /// The unjittered depths, `linspace(min_depth, max_depth, n_pts_per_ray)`.
    pub fn depths(&self) -> Vec<f64> {
        linspace(self.min_depth, self.max_depth, self.n_pts_per_ray)
    }

    /// Depths for `n_rays` rays, jittered uniformly inside the bins between midpoints of
    /// neighbouring depths (the first and last bins end at `min_depth` and `max_depth`).
    ///
    /// Returns `n_rays · S` values, ray-major.
    pub(crate) fn jittered_depths(&self, n_rays: usize, rng: &mut impl Rng) -> Vec<f32> {
        let z = self.depths();
        let s = z.len();
        let lower: Vec<f64> = (0..s)
            .map(|i| {
                if i == 0 {
                    z[0]
                } else {
                    0.5 * (z[i - 1] + z[i])
                }
            })
            .collect();
        let upper: Vec<f64> = (0..s)
            .map(|i| {
                if i + 1 == s {
                    z[s - 1]
                } else {
                    0.5 * (z[i] + z[i + 1])
                }
            })
            .collect();
        let mut out = Vec::with_capacity(n_rays * s);
        for _ in 0..n_rays {
            for i in 0..s {
                let u: f64 = rng.random();
                out.push((lower[i] + (upper[i] - lower[i]) * u) as f32);
            }
        }
        out
    }

    /// Samples every ray at the same depths (`jitter = None`) or at per-ray jittered depths.
    ///
    /// `rays`: N rays; returns points `(N, S, 3)` and lengths `(N, S, 1)`, in the rays' dtype
    /// (float64 rays get depths computed in float64).
    pub fn sample(
        &self,
        rays: &Rays,
        jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<RaySamples> {
        let lengths = self.lengths(rays, jitter)?;
        let points = sample_points(&rays.origins, &rays.directions, &lengths)?;
        Ok(RaySamples { points, lengths })
    }

    /// The sample depths of [`StratifiedSampler::sample`] alone, `(N, S, 1)` in the rays'
    /// dtype (for fields that place the points themselves, [`crate::field::FieldFastPaths::render_fused`]).
    pub fn lengths(&self, rays: &Rays, jitter: Option<&mut dyn rand::RngCore>) -> Result<Tensor> {
        let lengths = self.compact_lengths(rays, jitter)?;
        let (_, s, _) = lengths.dims3()?;
        Ok(lengths.broadcast_as((rays.len(), s, 1))?.contiguous()?)
    }

    /// The sample depths without repeats: `(1, S, 1)` shared by every ray without jitter,
    /// `(N, S, 1)` with it; in the rays' dtype.
    pub fn compact_lengths(
        &self,
        rays: &Rays,
        jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<Tensor> {
        let n = rays.len();
        let s = self.n_pts_per_ray;
        let device = rays.origins.device();
        let dtype = rays.origins.dtype();
        Ok(match jitter {
            None => shared_lengths(self.depths(), dtype, device)?,
            Some(rng) => {
                Tensor::from_vec(self.jittered_depths(n, &mut RngRef(rng)), (n, s, 1), device)?
                    .to_dtype(dtype)?
            }
        })
    }
}

/// Adapts a `dyn RngCore` to the generic `Rng` methods.
struct RngRef<'a>(&'a mut dyn rand::RngCore);

impl rand::RngCore for RngRef<'_> {
    fn next_u32(&mut self) -> u32 {
        self.0.next_u32()
    }
    fn next_u64(&mut self) -> u64 {
        self.0.next_u64()
    }
    fn fill_bytes(&mut self, dst: &mut [u8]) {
        self.0.fill_bytes(dst)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;
    use glam::DVec3;
    use nerf_core::camera::surround_cameras;
    use rand::SeedableRng;

    fn rays(n_w: usize, n_h: usize) -> Rays {
        let cam = surround_cameras(3.0, 20, DVec3::Y, 1.0)[1];
        Rays::for_image(
            &nerf_core::camera::Camera::from(cam),
            n_w,
            n_h,
            &Device::Cpu,
        )
        .unwrap()
    }

    #[test]
    fn shapes_for_several_sizes() {
        for (w, h, s) in [(3, 2, 1), (8, 8, 7), (10, 3, 64)] {
            let sampler = StratifiedSampler::new(s, 0.5, 5.0).unwrap();
            let out = sampler.sample(&rays(w, h), None).unwrap();
            assert_eq!(out.points.dims(), &[w * h, s, 3]);
            assert_eq!(out.lengths.dims(), &[w * h, s, 1]);
        }
    }

    #[test]
    fn points_lie_on_their_rays() {
        let r = rays(4, 3);
        let sampler = StratifiedSampler::new(5, 1.0, 3.0).unwrap();
        let out = sampler.sample(&r, None).unwrap();
        let p = out.points.to_vec3::<f32>().unwrap();
        let o = r.origins.to_vec2::<f32>().unwrap();
        let d = r.directions.to_vec2::<f32>().unwrap();
        let z = [1.0, 1.5, 2.0, 2.5, 3.0];
        for i in 0..12 {
            for (j, t) in z.iter().enumerate() {
                for k in 0..3 {
                    assert!((p[i][j][k] - (o[i][k] + t * d[i][k])).abs() < 1e-6);
                }
            }
        }
    }

    #[test]
    fn jitter_stays_in_bins_and_is_sorted() {
        let sampler = StratifiedSampler::new(16, 2.0, 6.0).unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let z = sampler.jittered_depths(50, &mut rng);
        for ray in z.chunks(16) {
            assert!(ray.windows(2).all(|w| w[0] <= w[1]));
            assert!(ray[0] >= 2.0 && ray[15] <= 6.0);
        }
        let out = sampler.sample(&rays(5, 10), Some(&mut rng)).unwrap();
        assert_eq!(out.lengths.dims(), &[50, 16, 1]);
    }

    #[test]
    fn rejects_bad_settings() {
        assert!(StratifiedSampler::new(0, 0.0, 1.0).is_err());
        assert!(StratifiedSampler::new(4, -1.0, 1.0).is_err());
        assert!(StratifiedSampler::new(4, 3.0, 1.0).is_err());
        assert!(StratifiedSampler::new(4, 0.0, f64::NAN).is_err());
        assert!(StratifiedSampler::new(1, 2.0, 2.0).is_ok());
    }
}
