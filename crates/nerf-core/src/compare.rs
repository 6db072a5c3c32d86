//! Comparing tensors: how far one is from another (the fused kernels' tests, resumed training
//! against a straight run, …).

use candle_core::{DType, Result, Tensor};

/// The largest absolute difference between `a` and `b` over all elements, as f32.
///
/// `a`, `b`: any shapes with the same number of elements (compared in row-major order), any
/// float dtype.
pub fn max_abs_difference(a: &Tensor, b: &Tensor) -> Result<f32> {
    a.flatten_all()?
        .sub(&b.flatten_all()?)?
        .abs()?
        .max_all()?
        .to_dtype(DType::F32)?
        .to_scalar::<f32>()
}

/// The largest absolute value over all elements of `t` (any shape, any float dtype), as f32.
pub fn max_abs_value(t: &Tensor) -> Result<f32> {
    t.abs()?.max_all()?.to_dtype(DType::F32)?.to_scalar::<f32>()
}

/// Panics unless `actual` is within `rel_tol · max(1, max|expected|)` of `expected` in every
/// element: the tolerance scales with the reference's largest value, so large gradients are
/// held to the same relative precision as small ones. The message names `what`, the largest
/// difference and the scale. (The fused kernels' tests hold their gradients to their twins'
/// with it.)
///
/// `actual`, `expected`: any shapes with the same number of elements, any float dtype.
pub fn assert_close(actual: &Tensor, expected: &Tensor, rel_tol: f32, what: &str) {
    let difference = max_abs_difference(actual, expected).expect("comparable tensors");
    let scale = max_abs_value(expected).expect("a float tensor");
    assert!(
        difference <= rel_tol * scale.max(1.0),
        "{what}: differs by {difference} (scale {scale})"
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    #[test]
    fn largest_difference_over_all_elements() {
        let a = Tensor::new(&[[1.0f32, 2.0], [3.0, 4.0]], &Device::Cpu).unwrap();
        let b = Tensor::new(&[1.5f32, 2.0, 0.5, 4.25], &Device::Cpu).unwrap();
        assert_eq!(max_abs_difference(&a, &b).unwrap(), 2.5);
        assert_eq!(max_abs_difference(&a, &a).unwrap(), 0.0);
        let short = Tensor::new(&[1.0f32], &Device::Cpu).unwrap();
        assert!(max_abs_difference(&a, &short).is_err());
        assert_eq!(max_abs_value(&b).unwrap(), 4.25);
    }

    #[test]
    fn closeness_is_relative_to_the_largest_expected_value() {
        let expected = Tensor::new(&[100.0f32, -200.0], &Device::Cpu).unwrap();
        let within = Tensor::new(&[100.0f32, -199.99], &Device::Cpu).unwrap();
        assert_close(&within, &expected, 1e-4, "within the tolerance");
        let small = Tensor::new(&[0.001f32], &Device::Cpu).unwrap();
        let near = Tensor::new(&[0.0015f32], &Device::Cpu).unwrap();
        assert_close(&near, &small, 1e-3, "a scale below 1 counts as 1");
    }

    #[test]
    #[should_panic(expected = "outside: differs by")]
    fn a_difference_beyond_the_tolerance_panics() {
        let expected = Tensor::new(&[100.0f32, -200.0], &Device::Cpu).unwrap();
        let outside = Tensor::new(&[100.0f32, -199.9], &Device::Cpu).unwrap();
        assert_close(&outside, &expected, 1e-4, "outside");
    }
}
