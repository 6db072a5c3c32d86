//! Coarse-to-fine (hierarchical) sampling, as pytorch3d's NeRF project does it with its
//! `ProbabilisticRaysampler`: a coarse pass renders the stratified samples, the weights of
//! that pass define a piecewise-constant density over the ray (on the bins between the
//! midpoints of neighbouring coarse samples), and `n_pts_per_ray_fine` more depths are drawn
//! from it by inverse transform sampling (`sample_pdf`). The fine pass renders the coarse
//! and fine depths together, sorted. One field serves both passes (pytorch3d trains a second
//! network for the fine pass; here the option is a sampling strategy for any field).
//!
//! The fine depths are chosen from values, without a gradient (pytorch3d detaches them too);
//! gradients flow through the fine pass's field evaluations.

use std::sync::Arc;

use anyhow::Result;
use candle_core::{DType, Tensor};
use rand::Rng;

use crate::field::Field;
use crate::ray_sampler::RaySampler;
use crate::sampler::{RaySamples, StratifiedSampler};
use crate::sampler_kind::{SamplerKind, SamplerSettings};
use nerf_core::rays::Rays;
use nerf_core::volume::{deltas, weights};
use nerf_kernels::sample_points::sample_points;

/// The `stratified` sampler kind ([`crate::sampler_registry`]): the homework's
/// stratified depths, refined coarse-to-fine when `n_pts_per_ray_fine` > 0.
pub(crate) const STRATIFIED: SamplerKind = SamplerKind {
    name: "stratified",
    build: stratified_kind,
};

fn stratified_kind(s: &SamplerSettings) -> Result<Arc<dyn RaySampler>> {
    anyhow::ensure!(
        s.n_pts_far == 0,
        "sampler.n_pts_far: only with type depth_then_disparity"
    );
    let coarse = StratifiedSampler::new(s.n_pts_per_ray, s.min_depth, s.max_depth)?;
    Ok(match s.n_pts_per_ray_fine {
        0 => Arc::new(coarse),
        n_fine => Arc::new(CoarseToFineSampler { coarse, n_fine }),
    })
}

/// Coarse-to-fine sampling (`sampler.n_pts_per_ray_fine` > 0): the field at the stratified
/// depths gives weights (no gradient), `n_fine` more depths are drawn from them, and the
/// renderer composites coarse and fine depths together.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CoarseToFineSampler {
    /// The coarse pass's stratified depths.
    pub coarse: StratifiedSampler,
    /// Depths per ray added from the coarse weights (at least 1).
    pub n_fine: usize,
}

impl RaySampler for CoarseToFineSampler {
    fn drawn_per_ray(&self) -> usize {
        self.coarse.n_pts_per_ray
    }

    fn compact_lengths(
        &self,
        rays: &Rays,
        jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<Tensor> {
        self.coarse.compact_lengths(rays, jitter)
    }

    fn samples_per_ray(&self) -> usize {
        self.coarse.n_pts_per_ray + self.n_fine
    }

    /// The coarse pass, then the coarse and fine depths together.
    fn evaluations_per_ray(&self) -> usize {
        2 * self.coarse.n_pts_per_ray + self.n_fine
    }

    fn refines(&self) -> bool {
        true
    }

    fn refine(
        &self,
        field: &dyn Field,
        rays: &Rays,
        coarse: Tensor,
        jitter: Option<&mut dyn rand::RngCore>,
    ) -> Result<Tensor> {
        let deltas = deltas(&coarse)?;
        let points = sample_points(&rays.origins, &rays.directions, &coarse)?;
        let samples = RaySamples {
            points,
            lengths: coarse,
        };
        let density = field
            .evaluate(&samples, &deltas, &rays.directions)?
            .density
            .detach();
        let weights = weights(&density, &deltas)?;
        Ok(
            fine_lengths(&samples.lengths, &weights, self.n_fine, jitter)?
                .to_dtype(rays.origins.dtype())?,
        )
    }
}

/// Added to every coarse weight before normalising, so that a ray with zero weight everywhere
/// samples its bins uniformly (pytorch3d's `sample_pdf` eps).
pub(crate) const WEIGHT_EPS: f32 = 1e-5;

/// Inverse transform sampling of a piecewise-constant density: bin `j` spans
/// `[edges[j], edges[j + 1]]` and has mass `weights[j] + WEIGHT_EPS` (normalised); each
/// `u ∈ [0, 1]` maps to the depth where the cumulative mass reaches `u` (linear inside a bin).
/// pytorch3d's `sample_pdf` for one ray: `edges` has one more value than `weights`, and the
/// result has one depth per `u`, in the order of `u` (increasing when `u` is).
pub(crate) fn sample_pdf(edges: &[f32], weights: &[f32], u: &[f32]) -> Vec<f32> {
    debug_assert_eq!(edges.len(), weights.len() + 1);
    let total: f32 = weights.iter().map(|w| w + WEIGHT_EPS).sum();
    // cdf[0] = 0, cdf[j + 1] = mass of bins 0..=j.
    let mut cdf = Vec::with_capacity(edges.len());
    cdf.push(0f32);
    let mut sum = 0f32;
    for w in weights {
        sum += (w + WEIGHT_EPS) / total;
        cdf.push(sum);
    }
    let last = cdf.len() - 1;
    // Exactly 1, so that u = 1 maps to the far edge whatever the rounding of the sum.
    cdf[last] = 1.0;
    u.iter()
        .map(|&u| {
            // The first cdf entry above u (searchsorted, right = True), and the bin edges
            // either side of it (both the last one past the end).
            let index = cdf.partition_point(|&c| c <= u);
            let (below, above) = (index.saturating_sub(1), index.min(last));
            let mut denom = cdf[above] - cdf[below];
            if denom < WEIGHT_EPS {
                denom = 1.0;
            }
            let t = (u - cdf[below]) / denom;
            edges[below] + t * (edges[above] - edges[below])
        })
        .collect()
}

/// The quantiles a ray's fine depths are drawn at: `linspace(0, 1, n)` when rendering, `n`
/// sorted uniform values when training (`jitter`).
pub(crate) fn fine_quantiles(n: usize, jitter: Option<&mut dyn rand::RngCore>) -> Vec<f32> {
    match jitter {
        None => nerf_core::rays::linspace(0.0, 1.0, n)
            .into_iter()
            .map(|v| v as f32)
            .collect(),
        Some(rng) => {
            let mut u: Vec<f32> = (0..n).map(|_| rng.random::<f32>()).collect();
            u.sort_unstable_by(f32::total_cmp);
            u
        }
    }
}

/// The fine pass's depths: each ray's coarse `lengths` `(N, S, 1)` and `n_fine` depths drawn
/// from its coarse `weights` `(N, S, 1)` ([`sample_pdf`] over the bins between midpoints of
/// neighbouring coarse depths, weights of the interior samples, as pytorch3d), merged and
/// sorted: `(N, S + n_fine, 1)` f32. Rays with fewer than 3 coarse samples get their coarse
/// depths repeated at their first bin edge instead (there is no interior bin).
pub(crate) fn fine_lengths(
    lengths: &Tensor,
    weights: &Tensor,
    n_fine: usize,
    mut jitter: Option<&mut dyn rand::RngCore>,
) -> Result<Tensor> {
    let (n, s, _) = lengths.dims3()?;
    let values = |t: &Tensor| -> Result<Vec<f32>> {
        Ok(t.detach()
            .to_dtype(DType::F32)?
            .flatten_all()?
            .to_vec1::<f32>()?)
    };
    let (z, w) = (values(lengths)?, values(weights)?);
    let width = s + n_fine;
    let mut out = Vec::with_capacity(n * width);
    for ray in 0..n {
        let (z, w) = (&z[ray * s..(ray + 1) * s], &w[ray * s..(ray + 1) * s]);
        let rng = jitter.as_mut().map(|r| &mut **r as &mut dyn rand::RngCore);
        let u = fine_quantiles(n_fine, rng);
        let mut merged = z.to_vec();
        if s >= 3 {
            let mids: Vec<f32> = z.windows(2).map(|p| 0.5 * (p[0] + p[1])).collect();
            merged.extend(sample_pdf(&mids, &w[1..s - 1], &u));
        } else {
            merged.extend(std::iter::repeat_n(z[0], n_fine));
        }
        merged.sort_unstable_by(f32::total_cmp);
        out.extend(merged);
    }
    Ok(Tensor::from_vec(out, (n, width, 1), lengths.device())?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;
    use rand::SeedableRng;

    #[test]
    fn uniform_weights_give_evenly_spread_depths() {
        // Equal bins of equal mass: the cdf is linear, so u maps linearly onto [0, 4].
        let edges = [0.0, 1.0, 2.0, 3.0, 4.0];
        let u: Vec<f32> = (0..=8).map(|k| k as f32 / 8.0).collect();
        let got = sample_pdf(&edges, &[0.3; 4], &u);
        for (g, u) in got.iter().zip(&u) {
            assert!((g - 4.0 * u).abs() < 1e-5, "{g} for u = {u}");
        }
    }

    #[test]
    fn all_mass_in_one_bin_puts_every_sample_there() {
        let edges = [2.0, 2.5, 3.0, 3.5, 4.0];
        let weights = [0.0, 0.0, 5.0, 0.0];
        let u: Vec<f32> = (0..16).map(|k| (k as f32 + 0.5) / 16.0).collect();
        let got = sample_pdf(&edges, &weights, &u);
        // Bin 2 holds (5 + eps) / (5 + 4 eps) of the mass; only the outermost quantiles,
        // within eps of 0 or 1, could fall outside it.
        for g in &got {
            assert!((3.0..=3.5).contains(g), "{g}");
        }
        // Inside the bin the cdf is linear: depth 3 + 0.5 (u − c0) / (c1 − c0).
        let (c0, c1) = (2e-5 / (5.0 + 4e-5), (5.0 + 3e-5) / (5.0 + 4e-5));
        for (g, u) in got.iter().zip(&u) {
            let expected = 3.0 + 0.5 * (u - c0) / (c1 - c0);
            assert!((g - expected).abs() < 1e-5, "{g} vs {expected}");
        }
    }

    #[test]
    fn matches_a_float64_recomputation_of_the_inverse_cdf() {
        let edges: Vec<f32> = (0..9).map(|k| 2.0 + 0.5 * k as f32).collect();
        let weights = [0.1f32, 0.0, 0.7, 0.05, 0.9, 0.0, 0.2, 0.3];
        let u: Vec<f32> = (0..32).map(|k| (k as f32 * 0.618).fract()).collect();
        let got = sample_pdf(&edges, &weights, &u);
        let total: f64 = weights.iter().map(|&w| w as f64 + 1e-5).sum();
        for (g, &u) in got.iter().zip(&u) {
            // Walk the bins until the mass reaches u.
            let mut below = 0.0;
            let mut depth = f64::NAN;
            for (j, &w) in weights.iter().enumerate() {
                let mass = (w as f64 + 1e-5) / total;
                if (u as f64) < below + mass {
                    let t = (u as f64 - below) / mass;
                    depth = edges[j] as f64 + t * (edges[j + 1] - edges[j]) as f64;
                    break;
                }
                below += mass;
            }
            assert!((*g as f64 - depth).abs() < 1e-4, "u {u}: {g} vs {depth}");
        }
    }

    #[test]
    fn matches_pytorch3d_hierarchical_sampling() {
        // tests/fixtures/sample_pdf.json is written by scripts/make_sample_pdf_fixture.py with
        // PyTorch (pytorch3d's sample_pdf and the NeRF project's concatenate-and-sort).
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../tests/fixtures/sample_pdf.json"
        );
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let floats = |key: &str| -> Vec<f32> {
            json[key]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap() as f32)
                .collect()
        };
        let size = |key: &str| json[key].as_u64().unwrap() as usize;
        let (n, s, fine) = (size("rays"), size("coarse"), size("fine"));
        let (z, w, u_random) = (floats("lengths"), floats("weights"), floats("u_random"));
        let close = |got: &[f32], expected: &[f32], what: &str| {
            assert_eq!(got.len(), expected.len());
            for (k, (g, e)) in got.iter().zip(expected).enumerate() {
                assert!(
                    (g - e).abs() <= 2e-5 * e.abs().max(1.0),
                    "{what}[{k}]: {g} vs {e}"
                );
            }
        };
        // sample_pdf at PyTorch's random quantiles, ray by ray.
        let fine_random = floats("fine_random");
        for ray in 0..n {
            let z = &z[ray * s..(ray + 1) * s];
            let mids: Vec<f32> = z.windows(2).map(|p| 0.5 * (p[0] + p[1])).collect();
            let got = sample_pdf(
                &mids,
                &w[ray * s + 1..(ray + 1) * s - 1],
                &u_random[ray * fine..(ray + 1) * fine],
            );
            close(
                &got,
                &fine_random[ray * fine..(ray + 1) * fine],
                "fine_random",
            );
        }
        // The render-time fine pass depths (linspace quantiles), merged and sorted.
        let dev = &Device::Cpu;
        let lengths = Tensor::from_vec(z.clone(), (n, s, 1), dev).unwrap();
        let weights = Tensor::from_vec(w.clone(), (n, s, 1), dev).unwrap();
        let merged = fine_lengths(&lengths, &weights, fine, None)
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        close(&merged, &floats("merged_render"), "merged_render");
    }

    #[test]
    fn fine_lengths_are_sorted_and_keep_the_coarse_depths() {
        let dev = &Device::Cpu;
        let (n, s, fine) = (3, 8, 5);
        let coarse: Vec<f32> = (0..n * s).map(|k| 2.0 + 0.5 * (k % s) as f32).collect();
        let weights: Vec<f32> = (0..n * s).map(|k| ((k * 7) % 5) as f32).collect();
        let lengths = Tensor::from_vec(coarse.clone(), (n, s, 1), dev).unwrap();
        let w = Tensor::from_vec(weights, (n, s, 1), dev).unwrap();
        let mut rng = rand::rngs::StdRng::seed_from_u64(2);
        for jitter in [false, true] {
            let rng: Option<&mut dyn rand::RngCore> = if jitter { Some(&mut rng) } else { None };
            let out = fine_lengths(&lengths, &w, fine, rng).unwrap();
            assert_eq!(out.dims(), &[n, s + fine, 1]);
            let v = out.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            for (ray, z) in v.chunks(s + fine).enumerate() {
                assert!(z.windows(2).all(|p| p[0] <= p[1]));
                for c in &coarse[ray * s..(ray + 1) * s] {
                    assert!(z.contains(c));
                }
                // Fine depths lie between the first and last midpoints.
                assert!(z.iter().all(|&d| (2.0..=5.5).contains(&d)));
            }
        }
    }
}
