//! mip-NeRF 360's distortion loss (Barron et al. 2022, eq. 15), written once: the maths of one
//! ray, its gradient with respect to the weights, and the normalised ray distance it is
//! measured in.
//!
//! A ray's samples are intervals `[a_i, b_i]` of the normalised distance `s ∈ [0, 1]`, with
//! midpoints `m_i = (a_i + b_i) / 2`, widths `d_i = b_i − a_i` and rendering weights `w_i`:
//!
//! `L = Σ_i Σ_j w_i w_j |m_i − m_j| + (1/3) Σ_i w_i² d_i`.
//!
//! The first term pulls a ray's weight together (a veil in front of the object costs as much
//! as the distance between them), the second shrinks each interval's share. With the
//! midpoints in increasing order the double sum is `2 Σ_i w_i (m_i W_{<i} − X_{<i})`, where
//! `W_{<i} = Σ_{j<i} w_j` and `X_{<i} = Σ_{j<i} w_j m_j`, so a ray costs O(n) (the paper's
//! closed form), and
//!
//! `∂L/∂w_k = 2 Σ_j w_j |m_k − m_j| + (2/3) w_k d_k`, with
//! `Σ_j w_j |m_k − m_j| = m_k W_{<k} − X_{<k} + X_{>k} − m_k W_{>k}`.
//!
//! The distance `s` is the sampler's own spacing ([`RaySpacing`]): the coordinate in which its
//! bins are equal, mapped onto `[0, 1]` from the near to the far bound, as mip-NeRF 360 and
//! nerfacto measure it (`s = (g(t) − g(near)) / (g(far) − g(near))`).

/// The normalised ray distance `s(t) ∈ [0, 1]` of a sampler: where its bins are equal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RaySpacing {
    /// Uniform in depth on `[near, far]` (the stratified sampler): `s = (t − near) / (far − near)`.
    Linear {
        /// Depth at `s = 0`.
        near: f64,
        /// Depth at `s = 1`.
        far: f64,
    },
    /// Uniform in depth on `[near, switch]`, which takes the first `linear_share` of `s`, then
    /// uniform in disparity `1/t` on `[switch, far]` (the depth-then-disparity sampler).
    LinearThenDisparity {
        /// Depth at `s = 0`.
        near: f64,
        /// Depth at `s = linear_share`.
        switch: f64,
        /// Depth at `s = 1`.
        far: f64,
        /// The share of `s` spaced in depth, in `(0, 1)`.
        linear_share: f64,
    },
}

impl RaySpacing {
    /// `s(t)`, clamped to `[0, 1]` (a depth past `far`, such as the last sample's end at
    /// `t + 1e10`, is at 1).
    pub(crate) fn normalised(&self, t: f64) -> f64 {
        let s = match *self {
            Self::Linear { near, far } => (t - near) / (far - near),
            Self::LinearThenDisparity {
                near,
                switch,
                far,
                linear_share,
            } => {
                if t <= switch {
                    linear_share * (t - near) / (switch - near)
                } else {
                    let (a, b) = (1.0 / switch, 1.0 / far);
                    linear_share + (1.0 - linear_share) * (a - 1.0 / t) / (a - b)
                }
            }
        };
        if s.is_nan() {
            return 1.0;
        }
        s.clamp(0.0, 1.0)
    }

    /// The interval `[s(t), s(t + delta)]` of a sample at depth `t` whose spacing to the next
    /// is `delta` ([`nerf_core::volume::spacing`]).
    #[inline]
    pub(crate) fn interval(&self, t: f32, delta: f32) -> (f32, f32) {
        let t = f64::from(t);
        (
            self.normalised(t) as f32,
            self.normalised(t + f64::from(delta)) as f32,
        )
    }
}

/// The distortion loss of one ray: weights `w` and intervals `[start_i, end_i]` (n each, in
/// increasing order along the ray), in O(n).
pub(crate) fn ray_distortion(w: &[f32], start: &[f32], end: &[f32]) -> f32 {
    let (mut w_before, mut x_before, mut total) = (0f64, 0f64, 0f64);
    for i in 0..w.len() {
        let (wi, a, b) = (f64::from(w[i]), f64::from(start[i]), f64::from(end[i]));
        let m = 0.5 * (a + b);
        total += 2.0 * wi * (m * w_before - x_before) + wi * wi * (b - a) / 3.0;
        w_before += wi;
        x_before += wi * m;
    }
    total as f32
}

/// `∂L/∂w` of [`ray_distortion`] into `grad` (n), in O(n).
pub(crate) fn ray_distortion_gradient(w: &[f32], start: &[f32], end: &[f32], grad: &mut [f32]) {
    let mid = |i: usize| 0.5 * (f64::from(start[i]) + f64::from(end[i]));
    let (w_total, x_total) = (0..w.len()).fold((0f64, 0f64), |(wt, xt), i| {
        (wt + f64::from(w[i]), xt + f64::from(w[i]) * mid(i))
    });
    let (mut w_before, mut x_before) = (0f64, 0f64);
    for i in 0..w.len() {
        let (wi, m) = (f64::from(w[i]), mid(i));
        let w_after = w_total - w_before - wi;
        let x_after = x_total - x_before - wi * m;
        let spread = m * w_before - x_before + x_after - m * w_after;
        let width = f64::from(end[i]) - f64::from(start[i]);
        grad[i] = (2.0 * spread + 2.0 * wi * width / 3.0) as f32;
        w_before += wi;
        x_before += wi * m;
    }
}

/// `∂L/∂τ` of a loss `L(w)` from `∂L/∂w` (`g`), given the ray's weights `w` and the
/// transmittance after each sample `T_{i+1}` (as [`nerf_core::volume::ray_weights`] gives
/// them): `∂L/∂τ_i = T_{i+1} g_i − Σ_{j>i} w_j g_j` (the chain through
/// `w_i = T_i (1 − e^{−τ_i})`), written into `g` in place.
pub(crate) fn weight_gradient_to_optical_depth(
    w: &[f32],
    transmittance_after: &[f32],
    g: &mut [f32],
) {
    let mut suffix = 0f32;
    for i in (0..g.len()).rev() {
        let gi = g[i];
        g[i] = transmittance_after[i] * gi - suffix;
        suffix += w[i] * gi;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The O(n²) definition in f64.
    fn quadratic(w: &[f64], a: &[f64], b: &[f64]) -> f64 {
        let n = w.len();
        let m: Vec<f64> = (0..n).map(|i| 0.5 * (a[i] + b[i])).collect();
        let mut l = 0.0;
        for i in 0..n {
            for j in 0..n {
                l += w[i] * w[j] * (m[i] - m[j]).abs();
            }
            l += w[i] * w[i] * (b[i] - a[i]) / 3.0;
        }
        l
    }

    /// A ray of `n` random weights (summing to at most 1) on increasing random intervals.
    fn random_ray(n: usize, seed: u64) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let raw: Vec<f32> = (0..n).map(|_| rng.random::<f32>().powi(3)).collect();
        let sum: f32 = raw.iter().sum::<f32>() * 1.1;
        let w = raw.iter().map(|v| v / sum).collect();
        let mut edges: Vec<f32> = (0..=n).map(|_| rng.random::<f32>()).collect();
        edges.sort_by(f32::total_cmp);
        (w, edges[..n].to_vec(), edges[1..].to_vec())
    }

    #[test]
    fn linear_form_matches_the_quadratic_definition_in_f64() {
        for (n, seed) in [(1, 1), (2, 2), (7, 3), (64, 4), (160, 5)] {
            let (w, a, b) = random_ray(n, seed);
            let f = |v: &[f32]| v.iter().map(|&x| f64::from(x)).collect::<Vec<_>>();
            let want = quadratic(&f(&w), &f(&a), &f(&b));
            let got = f64::from(ray_distortion(&w, &a, &b));
            assert!(
                (got - want).abs() <= 1e-6 * want.max(1e-3),
                "{n}: {got} vs {want}"
            );
        }
        // By hand: two unit weights half a unit apart, zero widths: 2 · 0.5 = 1.
        let l = ray_distortion(&[1.0, 1.0], &[0.25, 0.75], &[0.25, 0.75]);
        assert!((l - 1.0).abs() < 1e-6);
        // One weight on one interval: w² d / 3.
        assert!((ray_distortion(&[0.9], &[0.2], &[0.5]) - 0.81 * 0.3 / 3.0).abs() < 1e-6);
    }

    #[test]
    fn weight_gradient_matches_finite_differences_of_the_definition() {
        let (w, a, b) = random_ray(40, 9);
        let f = |v: &[f32]| v.iter().map(|&x| f64::from(x)).collect::<Vec<_>>();
        let (wf, af, bf) = (f(&w), f(&a), f(&b));
        let mut grad = vec![0f32; w.len()];
        ray_distortion_gradient(&w, &a, &b, &mut grad);
        let h = 1e-6;
        for k in 0..w.len() {
            let (mut plus, mut minus) = (wf.clone(), wf.clone());
            plus[k] += h;
            minus[k] -= h;
            let fd = (quadratic(&plus, &af, &bf) - quadratic(&minus, &af, &bf)) / (2.0 * h);
            assert!(
                (f64::from(grad[k]) - fd).abs() < 1e-5 * fd.abs().max(1.0),
                "w{k}: {} vs {fd}",
                grad[k]
            );
        }
    }

    #[test]
    fn spacing_maps_near_to_0_far_to_1_and_is_continuous() {
        let lin = RaySpacing::Linear {
            near: 2.0,
            far: 6.0,
        };
        assert_eq!(lin.normalised(2.0), 0.0);
        assert_eq!(lin.normalised(5.0), 0.75);
        assert_eq!(lin.normalised(1e10), 1.0);
        assert_eq!(lin.normalised(0.0), 0.0);
        let piecewise = RaySpacing::LinearThenDisparity {
            near: 0.02,
            switch: 2.8,
            far: 1000.0,
            linear_share: 0.8,
        };
        assert_eq!(piecewise.normalised(0.02), 0.0);
        assert!((piecewise.normalised(1.41) - 0.4).abs() < 1e-12);
        assert!((piecewise.normalised(2.8) - 0.8).abs() < 1e-12);
        assert!((piecewise.normalised(2.8 + 1e-9) - 0.8).abs() < 1e-9);
        // Halfway in disparity between 1/2.8 and 1/1000.
        let half = 1.0 / (0.5 * (1.0 / 2.8 + 1.0 / 1000.0));
        assert!((piecewise.normalised(half) - 0.9).abs() < 1e-12);
        assert!((piecewise.normalised(1000.0) - 1.0).abs() < 1e-12);
        assert_eq!(piecewise.normalised(1e10), 1.0);
        let (a, b) = piecewise.interval(2.0, 1e10);
        assert!(a < 0.8 && b == 1.0);
    }
}
