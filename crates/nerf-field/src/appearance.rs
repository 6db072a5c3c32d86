//! Per-image appearance (NeRF-W's appearance embedding, nerfacto's `appearance_embedding`):
//! each training image `i` has a learnt vector `e_i` of `dim` numbers, and a colour MLP adds
//! `W · e_i` to its first hidden layer for the rays of that image, so that exposure and
//! white-balance changes between photos are explained per photo instead of by the scene.
//!
//! Held-out views have no vector of their own: they are rendered with the mean of the
//! training images' vectors (`W · mean(e)`), the protocol every figure in docs/own-scene.md
//! uses. (NeRF-W instead optimises a test image's vector on half of it; nerfstudio renders
//! with zeros or the mean.)
//!
//! Parameters, under `appearance.`: `embedding` `(images, dim)` (initialised U(−0.05, 0.05):
//! a small start, so the images begin alike) and `weight` `(hidden, dim)` (PyTorch's default
//! linear initialisation, no bias: the colour MLP's first layer has one).

use anyhow::Result;
use candle_core::Tensor;
use candle_nn::{Init, VarBuilder};

/// The parameter name of the per-image vectors `(images, dim)`.
pub const EMBEDDING: &str = "appearance.embedding";

/// Bound of the vectors' uniform initialisation.
pub(crate) const EMBEDDING_INIT: f64 = 0.05;

/// The sizes of a field's appearance embedding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AppearanceParams {
    /// Numbers per image's vector (`implicit_function.appearance_dim`).
    pub dim: usize,
    /// Training images (0 until the training set, or the checkpoint, says: no parameters).
    pub images: usize,
}

/// The learnt appearance of a field's training images.
#[derive(Debug, Clone)]
pub(crate) struct Appearance {
    /// `(images, dim)` per-image vectors.
    embedding: Tensor,
    /// `(hidden, dim)`: how a vector moves the colour MLP's first hidden layer.
    weight: Tensor,
}

impl Appearance {
    /// The parameters for `params` (none while `params.images` is 0), created in or loaded
    /// from `vb` (its prefix: the field's), feeding a layer of `hidden` units.
    pub(crate) fn new(
        params: &AppearanceParams,
        hidden: usize,
        vb: &VarBuilder,
    ) -> Result<Option<Self>> {
        if params.images == 0 || params.dim == 0 {
            return Ok(None);
        }
        let vb = vb.pp("appearance");
        let embedding = vb.get_with_hints(
            (params.images, params.dim),
            "embedding",
            Init::Uniform {
                lo: -EMBEDDING_INIT,
                up: EMBEDDING_INIT,
            },
        )?;
        let bound = 1.0 / (params.dim as f64).sqrt();
        let weight = vb.get_with_hints(
            (hidden, params.dim),
            "weight",
            Init::Uniform {
                lo: -bound,
                up: bound,
            },
        )?;
        Ok(Some(Self { embedding, weight }))
    }

    /// The first-layer term of each ray: `W · e_{camera_index[r]}` `(N, hidden)` for
    /// `camera_index` `(N,)` u32 (training rays), or `W · mean(e)` `(1, hidden)` for rays of
    /// no training image (`None`), to broadcast over them.
    pub(crate) fn per_ray(&self, camera_index: Option<&Tensor>) -> Result<Tensor> {
        let vectors = match camera_index {
            Some(index) => self.embedding.index_select(index, 0)?,
            None => self.embedding.mean_keepdim(0)?,
        };
        Ok(vectors.matmul(&self.weight.t()?)?)
    }

    /// The same parameters detached from the autograd graph, for rendering.
    pub(crate) fn detached(&self) -> Self {
        Self {
            embedding: self.embedding.detach(),
            weight: self.weight.detach(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::VarMap;

    #[test]
    fn per_ray_terms_are_each_images_vector_or_their_mean() {
        let dev = Device::Cpu;
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
        let params = AppearanceParams { dim: 3, images: 4 };
        let app = Appearance::new(&params, 5, &vb).unwrap().unwrap();
        let e = app.embedding.to_vec2::<f32>().unwrap();
        let w = app.weight.to_vec2::<f32>().unwrap();
        let term = |v: &[f32]| -> Vec<f32> {
            (0..5)
                .map(|h| (0..3).map(|k| w[h][k] * v[k]).sum())
                .collect()
        };
        let index = Tensor::new(&[2u32, 0, 2], &dev).unwrap();
        let got = app.per_ray(Some(&index)).unwrap().to_vec2::<f32>().unwrap();
        for (row, image) in got.iter().zip([2usize, 0, 2]) {
            let want = term(&e[image]);
            assert!(row.iter().zip(&want).all(|(a, b)| (a - b).abs() < 1e-6));
        }
        let mean: Vec<f32> = (0..3)
            .map(|k| e.iter().map(|v| v[k]).sum::<f32>() / 4.0)
            .collect();
        let got = app.per_ray(None).unwrap().to_vec2::<f32>().unwrap();
        assert_eq!(got.len(), 1);
        assert!(got[0]
            .iter()
            .zip(term(&mean))
            .all(|(a, b)| (a - b).abs() < 1e-6));
        // Named under the field's prefix; none without images.
        let names: Vec<String> = varmap.data().lock().unwrap().keys().cloned().collect();
        assert!(names.contains(&EMBEDDING.to_string()), "{names:?}");
        let none = AppearanceParams { dim: 3, images: 0 };
        assert!(Appearance::new(&none, 5, &vb).unwrap().is_none());
    }
}
