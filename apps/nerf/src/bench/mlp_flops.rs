//! Floating-point operations of the dense NeRF MLP (the homework's model), counted from its
//! parameters' shapes, for the NeRF rows of `nerf bench`: each row's GFLOP/s and its fraction
//! of the same run's matrix-multiply rate ([`crate::bench::hash_grid_rows::GemmRates`]).
//!
//! Per sample, forward: every weight matrix `[out, in]` is `out·in` multiply-adds, 2 FLOP
//! each. Biases, activations, the harmonic embedding and compositing are not counted (under
//! 1% of the matrices' work for the homework's sizes), so the rates are of the matrix work
//! alone, the part a gemm rate bounds. A training step counts 3× the forward: the backward
//! pass computes the gradients of each layer's input and of its weights, each a product of
//! the forward's size.

use nerf::io::parameter_shapes::ParameterShapes;

use crate::bench::hash_grid_rows::GemmRates;
use crate::bench::row::Throughput;

/// FLOP of a training step per sample against the forward's: forward and backward.
pub const TRAIN_FACTOR: f64 = 3.0;

/// FLOP of one sample through every weight matrix of `shapes`, forward.
pub fn forward_flop_per_sample(shapes: &ParameterShapes) -> f64 {
    shapes
        .iter()
        .filter(|(_, shape)| shape.len() == 2)
        .map(|(_, shape)| 2.0 * (shape[0] * shape[1]) as f64)
        .sum()
}

/// The throughput of `evaluated` samples of `flop_per_sample` each (of `drawn` drawn) on
/// `rays` rays in `seconds`, with its fractions of the run's gemm `rates`.
pub fn mlp_throughput(
    (rays, drawn, evaluated): (usize, usize, usize),
    flop_per_sample: f64,
    seconds: f64,
    rates: Option<&GemmRates>,
) -> Throughput {
    let per_second = |n: usize| Some(n as f64 / seconds);
    Throughput {
        rays_per_second: per_second(rays),
        drawn_samples_per_second: per_second(drawn),
        evaluated_samples_per_second: per_second(evaluated),
        flop_per_evaluated_sample: Some(flop_per_sample),
        ..GemmRates::throughput(rates, evaluated as f64 * flop_per_sample / seconds / 1e9)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf::field::nerf::{parameter_shapes, NerfParams};

    #[test]
    fn the_homework_nerf_counts_its_layers_by_hand() {
        // The homework's sizes: 6 and 2 harmonics, widths 128 and 64, 6 trunk layers.
        let params = NerfParams::default();
        // Point embedding 3 + 3·2·6 = 39, direction embedding 3 + 3·2·2 = 15; the trunk's
        // layer 3 takes the point embedding again.
        let trunk = 39 * 128 + 4 * 128 * 128 + (128 + 39) * 128;
        let heads = 128 + 128 * 128 + (128 + 15) * 64 + 64 * 3;
        let expected = 2.0 * (trunk + heads) as f64;
        assert_eq!(
            forward_flop_per_sample(&parameter_shapes(&params)),
            expected
        );
    }

    #[test]
    fn a_throughput_is_of_the_evaluated_samples() {
        let rates = GemmRates {
            mlp: 100.0,
            square: 200.0,
        };
        let t = mlp_throughput((10, 1000, 500), 2e6, 0.5, Some(&rates));
        assert_eq!(t.gflops, 2.0);
        assert_eq!(t.fraction_of_mlp_gemm, Some(0.02));
        assert_eq!(t.evaluated_samples_per_second, Some(1000.0));
        assert_eq!(t.drawn_samples_per_second, Some(2000.0));
    }
}
