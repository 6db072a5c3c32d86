//! Reading CPU tensor storage inside the fused kernels' `CustomOp`s.

use candle_core::{CpuStorage, Layout};

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
