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
    }
}
