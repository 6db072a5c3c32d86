//! The fused kernels as Candle ops: a [`CpuKernel`] says what an op computes from its inputs'
//! CPU storage (and, optionally, its backward pass), and [`Fused`] turns it into a Candle
//! `CustomOp1`/`CustomOp2`/`CustomOp3` — reading the inputs' storage and layouts, wrapping the
//! f32 result, answering Candle's name and backward calls — so that no kernel repeats Candle's
//! op boilerplate.

use candle_core::{CpuStorage, CustomOp1, CustomOp2, CustomOp3, Layout, Result, Shape, Tensor};

use crate::storage::contiguous_f32;

/// One input of a kernel's CPU forward pass: its storage and its layout in that storage.
#[derive(Clone, Copy)]
pub struct CpuInput<'a> {
    /// The storage the input's values sit in.
    pub storage: &'a CpuStorage,
    /// Where in `storage` the input lies, with its shape and strides.
    pub layout: &'a Layout,
}

impl<'a> CpuInput<'a> {
    /// The input's f32 values (any shape, contiguous); an error naming `op` if the layout is
    /// strided or the storage holds another dtype.
    pub fn f32(&self, op: &str) -> Result<&'a [f32]> {
        contiguous_f32(self.storage, self.layout, op)
    }

    /// The input's shape.
    pub fn shape(&self) -> &'a Shape {
        self.layout.shape()
    }

    /// Every input's f32 values (see [`CpuInput::f32`]), in order; an error naming `op` at the
    /// first input that is strided.
    pub fn all_f32<const N: usize>(inputs: &[Self; N], op: &str) -> Result<[&'a [f32]; N]> {
        let mut values = [&[] as &[f32]; N];
        for (v, input) in values.iter_mut().zip(inputs) {
            *v = input.f32(op)?;
        }
        Ok(values)
    }
}

/// What a kernel's forward pass returns: its f32 values, row-major, and their shape.
pub type KernelOutput = Result<(Vec<f32>, Shape)>;

/// What a kernel's backward pass returns: the gradient of each of its `N` inputs, in order,
/// each of that input's shape (`None`: the input gets no gradient).
pub type KernelGradients<const N: usize> = Result<[Option<Tensor>; N]>;

/// A fused CPU kernel with `N` inputs (1 to 3); run it through Candle as [`Fused`].
pub trait CpuKernel<const N: usize>: Send + Sync {
    /// The op's name, as Candle reports it.
    const NAME: &'static str;

    /// The output from the inputs' storage (the inputs as the op was applied to them).
    fn cpu_forward(&self, inputs: [CpuInput<'_>; N]) -> KernelOutput;

    /// The inputs' gradients from the inputs and the gradient of the output `grad` (the
    /// output's shape). By default the op has no backward pass: an error, as Candle's.
    fn gradients(&self, inputs: [&Tensor; N], grad: &Tensor) -> KernelGradients<N> {
        let _ = (inputs, grad);
        Err(candle_core::Error::BackwardNotSupported { op: Self::NAME })
    }
}

/// A [`CpuKernel`] as a Candle custom op (`apply_op1/2/3`, with or without backward): CPU only,
/// as the kernels are.
pub struct Fused<K>(pub K);

/// A kernel's output as Candle's CPU forward result.
fn to_storage((values, shape): (Vec<f32>, Shape)) -> Result<(CpuStorage, Shape)> {
    Ok((CpuStorage::F32(values), shape))
}

/// `Fused<K>` as Candle's `CustomOpN` for `K: CpuKernel<N>`: the three traits differ only in
/// how many (storage, layout) and argument pairs their methods take, so one body serves all.
macro_rules! custom_op {
    ($op:ident, $n:literal, $(($storage:ident, $layout:ident, $arg:ident, $grad:ident)),+) => {
        impl<K: CpuKernel<$n>> $op for Fused<K> {
            fn name(&self) -> &'static str {
                K::NAME
            }

            fn cpu_fwd(
                &self,
                $($storage: &CpuStorage, $layout: &Layout),+
            ) -> Result<(CpuStorage, Shape)> {
                let inputs = [$(CpuInput { storage: $storage, layout: $layout }),+];
                to_storage(self.0.cpu_forward(inputs)?)
            }

            #[allow(unused_parens)] // one input: `(Option<Tensor>)` is CustomOp1's `Option<Tensor>`
            fn bwd(
                &self,
                $($arg: &Tensor,)+
                _res: &Tensor,
                grad: &Tensor,
            ) -> Result<($(custom_op!(@option $arg)),+)> {
                let [$($grad),+] = self.0.gradients([$($arg),+], grad)?;
                Ok(($($grad),+))
            }
        }
    };
    (@option $arg:ident) => { Option<Tensor> };
}

custom_op!(CustomOp1, 1, (s1, l1, a1, g1));
custom_op!(CustomOp2, 2, (s1, l1, a1, g1), (s2, l2, a2, g2));
custom_op!(
    CustomOp3,
    3,
    (s1, l1, a1, g1),
    (s2, l2, a2, g2),
    (s3, l3, a3, g3)
);
