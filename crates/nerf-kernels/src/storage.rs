//! Reading CPU tensor storage inside the fused kernels' `CustomOp`s, and tensors' values on the
//! host in their backward passes.

use candle_core::{CpuStorage, Layout, Tensor};

/// The f32 values of a contiguous tensor (its layout's offsets into `storage`); an error naming
/// `op` if the layout is strided.
pub fn contiguous_f32<'a>(
    storage: &'a CpuStorage,
    layout: &Layout,
    op: &str,
) -> candle_core::Result<&'a [f32]> {
    match layout.contiguous_offsets() {
        Some((a, b)) => Ok(&storage.as_slice::<f32>()?[a..b]),
        None => candle_core::bail!("{op}: inputs must be contiguous"),
    }
}

/// Each tensor's f32 values on the host, row-major whatever its layout: how a backward pass
/// reads its inputs and its output's gradient.
pub fn host_values<const N: usize>(tensors: [&Tensor; N]) -> candle_core::Result<[Vec<f32>; N]> {
    let mut values: [Vec<f32>; N] = std::array::from_fn(|_| Vec::new());
    for (v, t) in values.iter_mut().zip(tensors) {
        *v = t.flatten_all()?.to_vec1::<f32>()?;
    }
    Ok(values)
}
