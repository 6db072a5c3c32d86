//! What the kernels' and fields' tests share: seeded uniform inputs, the gradients of a
//! weighted-sum loss, a gradient's values and size.

use candle_core::backprop::GradStore;
use candle_core::Tensor;
use rand::distr::uniform::SampleUniform;
use rand::distr::{Distribution, Uniform};
use rand::SeedableRng;

/// The gradients of `Σ out ⊙ weight` (`weight` broadcast to `out`'s shape): a loss that weighs
/// every output differently, so a gradient summed or routed wrongly shows.
pub fn weighted_sum_gradients(out: &Tensor, weight: &Tensor) -> GradStore {
    out.broadcast_mul(weight)
        .unwrap()
        .sum_all()
        .unwrap()
        .backward()
        .unwrap()
}

/// The gradient of `t` in `grads`, flattened to f32 values (panics if `t` has none).
pub fn gradient_values(grads: &GradStore, t: &Tensor) -> Vec<f32> {
    grads
        .get(t)
        .expect("a gradient")
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap()
}

/// `n` values drawn uniformly from `[lo, hi)` by a generator seeded with `seed`: the same
/// values on every run.
pub fn uniform_values<T: SampleUniform>(n: usize, seed: u64, lo: T, hi: T) -> Vec<T> {
    let range = Uniform::new(lo, hi).expect("lo < hi");
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    (0..n).map(|_| range.sample(&mut rng)).collect()
}

/// `Σ |t|` as an f32 (panics on a tensor that is not f32).
pub fn abs_sum(t: &Tensor) -> f32 {
    t.abs()
        .unwrap()
        .sum_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap()
}
