//! Sampling an unbounded scene: uniform in depth near the cameras, uniform in disparity (1/t)
//! beyond, out to a far plane (`sampler.type: depth_then_disparity`). The idea of nerfstudio's
//! `UniformLinDispPiecewiseSampler` and mip-NeRF 360's spacing: the scene's centre, where the
//! cameras look and the detail is, gets dense samples; the background, which the contraction
//! ([`nerf_core::contraction`]) squeezes into a thin shell, gets few, spaced evenly in the
//! contracted coordinate (at distance `r` it lands at `2 − 1/r`, linear in disparity).
//!
//! The ray is cut into `n_near + n_far` bins: `n_near` equal bins in depth on
//! `[min_depth, max_depth]`, then `n_far` bins equal in disparity on `[max_depth, far_depth]`.
//! One sample per bin: at the bin's middle (in its own spacing) when rendering, uniformly
//! inside it (in its own spacing) when training. Depths are shared by every ray (a fixed
//! switch depth, not the ray's exit from the unit cube), so rendering keeps the `(1, S, 1)`
//! compact form the skipping pass marches.

use std::sync::Arc;

use anyhow::{ensure, Result};
use candle_core::Tensor;
use rand::Rng;

use crate::ray_sampler::RaySampler;
use crate::sampler::shared_lengths;
use crate::sampler_kind::{SamplerKind, SamplerSettings};
use nerf_core::rays::Rays;
use nerf_kernels::distortion_loss::RaySpacing;

/// The `depth_then_disparity` sampler kind ([`crate::sampler_registry`]).
pub(crate) const DEPTH_THEN_DISPARITY: SamplerKind = SamplerKind {
    name: "depth_then_disparity",
    build: depth_then_disparity_kind,
};

fn depth_then_disparity_kind(s: &SamplerSettings) -> Result<Arc<dyn RaySampler>> {
    ensure!(
        s.n_pts_per_ray_fine == 0,
        "sampler.n_pts_per_ray_fine: coarse-to-fine sampling is for type stratified"
    );
    Ok(Arc::new(DepthThenDisparitySampler::new(
        s.n_pts_per_ray,
        (s.min_depth, s.max_depth),
        s.n_pts_far,
        s.far_depth,
    )?))
}

/// Uniform in depth on `[min_depth, max_depth]`, then uniform in disparity on
/// `[max_depth, far_depth]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DepthThenDisparitySampler {
    /// Bins (samples) uniform in depth (`sampler.n_pts_per_ray`, at least 1).
    pub n_near: usize,
    /// Start of the first bin (`sampler.min_depth`, ≥ 0).
    pub min_depth: f64,
    /// Where depth spacing gives way to disparity spacing (`sampler.max_depth`, > `min_depth`).
    pub max_depth: f64,
    /// Bins (samples) uniform in disparity (`sampler.n_pts_far`, at least 1).
    pub n_far: usize,
    /// End of the last bin (`sampler.far_depth`, > `max_depth`, finite).
    pub far_depth: f64,
}

impl DepthThenDisparitySampler {
    /// The sampler; an error naming the `sampler.…` key for bad counts or depths.
    pub(crate) fn new(
        n_near: usize,
        (min_depth, max_depth): (f64, f64),
        n_far: usize,
        far_depth: f64,
    ) -> Result<Self> {
        ensure!(n_near >= 1, "sampler.n_pts_per_ray must be at least 1");
        ensure!(
            n_far >= 1,
            "sampler.n_pts_far must be at least 1 with type depth_then_disparity"
        );
        ensure!(
            min_depth.is_finite() && max_depth.is_finite() && far_depth.is_finite(),
            "sampler.min_depth, max_depth and far_depth must be finite"
        );
        ensure!(min_depth >= 0.0, "sampler.min_depth must be non-negative");
        ensure!(
            min_depth < max_depth,
            "sampler.max_depth must exceed sampler.min_depth ({max_depth} <= {min_depth})"
        );
        ensure!(
            max_depth < far_depth,
            "sampler.far_depth must exceed sampler.max_depth ({far_depth} <= {max_depth})"
        );
        Ok(Self {
            n_near,
            min_depth,
            max_depth,
            n_far,
            far_depth,
        })
    }

    /// Samples per ray, `n_near + n_far`.
    pub(crate) fn n_samples(&self) -> usize {
        self.n_near + self.n_far
    }

    /// The `n_near + n_far + 1` bin edges, increasing from `min_depth` to `far_depth` (the
    /// tests' view of the bins `depths` draws in).
    #[cfg(test)]
    fn edges(&self) -> Vec<f64> {
        let near = (0..=self.n_near).map(|i| {
            let u = i as f64 / self.n_near as f64;
            self.min_depth + (self.max_depth - self.min_depth) * u
        });
        let far = (1..=self.n_far).map(|j| self.disparity_depth(j as f64 / self.n_far as f64));
        near.chain(far).collect()
    }

    /// The depth at fraction `u ∈ [0, 1]` of the disparity range: `1/t` linear from
    /// `1/max_depth` (u = 0) to `1/far_depth` (u = 1).
    fn disparity_depth(&self, u: f64) -> f64 {
        let (a, b) = (1.0 / self.max_depth, 1.0 / self.far_depth);
        if u >= 1.0 {
            return self.far_depth;
        }
        1.0 / (a + (b - a) * u)
    }

    /// The depth at fraction `u ∈ [0, 1]` of bin `i`, in the bin's own spacing (depth for the
    /// near bins, disparity for the far ones).
    pub(crate) fn depth_in_bin(&self, i: usize, u: f64) -> f64 {
        if i < self.n_near {
            let v = (i as f64 + u) / self.n_near as f64;
            self.min_depth + (self.max_depth - self.min_depth) * v
        } else {
            self.disparity_depth(((i - self.n_near) as f64 + u) / self.n_far as f64)
        }
    }

    /// The rendering depths: each bin's middle in its own spacing.
    pub(crate) fn depths(&self) -> Vec<f64> {
        (0..self.n_samples())
            .map(|i| self.depth_in_bin(i, 0.5))
            .collect()
    }

    /// Training depths for `n_rays` rays, each uniformly inside its bin (in the bin's
    /// spacing): `n_rays · S` values, ray-major.
    pub(crate) fn jittered_depths(&self, n_rays: usize, rng: &mut dyn rand::RngCore) -> Vec<f32> {
        let s = self.n_samples();
        let mut out = Vec::with_capacity(n_rays * s);
        for _ in 0..n_rays {
            for i in 0..s {
                let u: f64 = rng.random();
                out.push(self.depth_in_bin(i, u) as f32);
            }
        }
        out
    }
}

impl RaySampler for DepthThenDisparitySampler {
    fn drawn_per_ray(&self) -> usize {
        self.n_samples()
    }

    fn compact_lengths(
        &self,
        rays: &Rays,
        jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<Tensor> {
        let s = self.n_samples();
        let device = rays.origins.device();
        let dtype = rays.origins.dtype();
        Ok(match jitter {
            None => shared_lengths(self.depths(), dtype, device)?,
            Some(rng) => {
                let n = rays.len();
                Tensor::from_vec(self.jittered_depths(n, rng), (n, s, 1), device)?
                    .to_dtype(dtype)?
            }
        })
    }

    fn spacing(&self) -> Option<RaySpacing> {
        Some(RaySpacing::LinearThenDisparity {
            near: self.min_depth,
            switch: self.max_depth,
            far: self.far_depth,
            linear_share: self.n_near as f64 / self.n_samples() as f64,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use rand::SeedableRng;

    fn sampler() -> DepthThenDisparitySampler {
        DepthThenDisparitySampler::new(24, (0.05, 2.5), 16, 1000.0).unwrap()
    }

    #[test]
    fn edges_are_uniform_in_depth_then_in_disparity() {
        let s = sampler();
        let e = s.edges();
        assert_eq!(e.len(), 24 + 16 + 1);
        assert!((e[0] - 0.05).abs() < 1e-12 && (e[24] - 2.5).abs() < 1e-12);
        assert_eq!(e[40], 1000.0);
        let step = (2.5 - 0.05) / 24.0;
        for w in e[..=24].windows(2) {
            assert!((w[1] - w[0] - step).abs() < 1e-12);
        }
        let dstep = (1.0 / 1000.0 - 1.0 / 2.5) / 16.0;
        for w in e[24..].windows(2) {
            assert!((1.0 / w[1] - 1.0 / w[0] - dstep).abs() < 1e-12, "{w:?}");
        }
    }

    #[test]
    fn depths_are_increasing_bin_middles() {
        let s = sampler();
        let (z, e) = (s.depths(), s.edges());
        assert_eq!(z.len(), 40);
        for i in 0..40 {
            assert!(e[i] < z[i] && z[i] < e[i + 1], "bin {i}");
            if i < 24 {
                assert!((z[i] - 0.5 * (e[i] + e[i + 1])).abs() < 1e-12);
            } else {
                let mid = 0.5 * (1.0 / e[i] + 1.0 / e[i + 1]);
                assert!((1.0 / z[i] - mid).abs() < 1e-12);
            }
        }
        assert!(z.windows(2).all(|w| w[0] < w[1]));
        // The far samples are sparse: the last reaches tens of times the near range.
        assert!(z[39] > 20.0 * 2.5, "{}", z[39]);
    }

    #[test]
    fn jitter_stays_inside_the_bins() {
        let s = sampler();
        let e = s.edges();
        let mut rng = rand::rngs::StdRng::seed_from_u64(4);
        let z = s.jittered_depths(200, &mut rng);
        let mut spread = [f64::INFINITY, f64::NEG_INFINITY];
        for ray in z.chunks(40) {
            assert!(ray.windows(2).all(|w| w[0] <= w[1]));
            for (i, &t) in ray.iter().enumerate() {
                let t = f64::from(t);
                // f32 rounding of the depth.
                let tol = 1e-6 * e[i + 1];
                assert!(t >= e[i] - tol && t <= e[i + 1] + tol, "bin {i}: {t}");
                if i == 30 {
                    // Position in the bin, in disparity.
                    let u = (1.0 / t - 1.0 / e[i]) / (1.0 / e[i + 1] - 1.0 / e[i]);
                    spread = [spread[0].min(u), spread[1].max(u)];
                }
            }
        }
        // The jitter covers the bin (200 draws: the extremes within 5% of its ends).
        assert!(spread[0] < 0.05 && spread[1] > 0.95, "{spread:?}");
    }

    #[test]
    fn lengths_follow_the_rays_dtype_and_jitter() {
        let s = sampler();
        let cam = nerf_core::camera::surround_cameras(0.9, 4, glam::DVec3::Z, 1.0)[0];
        let rays =
            Rays::for_image(&nerf_core::camera::Camera::from(cam), 3, 2, &Device::Cpu).unwrap();
        let fixed = s.compact_lengths(&rays, None).unwrap();
        assert_eq!(fixed.dims(), &[1, 40, 1]);
        let dense = RaySampler::lengths(&s, &rays, None).unwrap();
        assert_eq!(dense.dims(), &[6, 40, 1]);
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let jittered = s.compact_lengths(&rays, Some(&mut rng)).unwrap();
        assert_eq!(jittered.dims(), &[6, 40, 1]);
        let rays64 = Rays {
            origins: rays.origins.to_dtype(DType::F64).unwrap(),
            directions: rays.directions.to_dtype(DType::F64).unwrap(),
            camera_index: None,
        };
        let z64 = s.compact_lengths(&rays64, None).unwrap();
        assert_eq!(z64.dtype(), DType::F64);
        let got = z64.flatten_all().unwrap().to_vec1::<f64>().unwrap();
        assert_eq!(got, s.depths());
    }

    #[test]
    fn rejects_bad_settings() {
        assert!(DepthThenDisparitySampler::new(0, (0.0, 1.0), 4, 10.0).is_err());
        assert!(DepthThenDisparitySampler::new(4, (0.0, 1.0), 0, 10.0).is_err());
        assert!(DepthThenDisparitySampler::new(4, (1.0, 1.0), 4, 10.0).is_err());
        assert!(DepthThenDisparitySampler::new(4, (0.0, 2.0), 4, 2.0).is_err());
        assert!(DepthThenDisparitySampler::new(4, (0.0, 2.0), 4, f64::INFINITY).is_err());
        assert!(DepthThenDisparitySampler::new(4, (-1.0, 2.0), 4, 9.0).is_err());
    }
}
