//! What the fused kernels' tests share: the gradients of a weighted-sum loss and a gradient's
//! values.

use candle_core::backprop::GradStore;
use candle_core::Tensor;

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
