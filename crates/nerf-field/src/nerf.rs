//! The homework's NeRF (`NeuralRadianceField`) as a candle-nn module.
//!
//! * Harmonic embedding with frequencies `2^0 … 2^(L−1)`, output `[sin(x·f), cos(x·f), x]`
//!   ordered channel-major as pytorch3d's `HarmonicEmbedding`.
//! * `mlp_xyz`: `n_layers_xyz` ReLU layers of width `n_hidden_neurons_xyz`; the xyz embedding is
//!   concatenated again before the layers in `append_xyz`.
//! * `density_layer`: Linear(hidden, 1) + ReLU.
//! * `intermediate_linear`: Linear(hidden, hidden); `color_layer`: Linear(hidden + dir_embedding,
//!   n_hidden_neurons_dir) + ReLU → Linear(·, 3) + sigmoid.
//!
//! The direction half of `color_layer.0` depends only on the ray, so it is applied once per ray
//! and broadcast over the samples (the same result as concatenating per sample).
//!
//! Parameters carry the PyTorch module names (`mlp_xyz.mlp.{i}.0.weight`,
//! `density_layer.0.weight`, `intermediate_linear.weight`, `color_layer.{0,2}.weight`, and
//! `.bias`), with PyTorch's shapes (`(out, in)`) and PyTorch's default `nn.Linear`
//! initialisation, U(−1/√fan_in, 1/√fan_in).

use anyhow::{ensure, Result};
use candle_core::{DType, Device, Tensor};
use candle_nn::{Init, Linear, VarBuilder, VarMap};

use crate::trainable::{
    linear_init_bound, load_parameters, seed_uniform, BoxedField, FieldSpec, TrainableField,
};
use nerf_checkpoint::parameter_shapes::ParameterShapes;
use nerf_kernels::nerf_mlp::{self, NerfLayers, NerfMlpShape};
use nerf_render::field::{Field, FieldFastPaths, FieldOutput};
use nerf_render::sampler::RaySamples;

/// The kind's name: what a config's `implicit_function.type` and a checkpoint call it.
pub(crate) const KIND: &str = "nerf";

/// The homework's NeRF as a config's `implicit_function` section with `type: nerf` writes
/// it, read straight from the section (a key left out takes the homework's default): the
/// model's sizes and its training's density noise. The kind's checks and registration are
/// [`crate::nerf_config`].
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NerfParams {
    /// Harmonic frequencies of the point embedding (`n_harmonic_functions_xyz`).
    pub n_harmonic_functions_xyz: usize,
    /// Harmonic frequencies of the direction embedding (`n_harmonic_functions_dir`).
    pub n_harmonic_functions_dir: usize,
    /// Width of the `mlp_xyz` trunk layers (`n_hidden_neurons_xyz`).
    pub n_hidden_neurons_xyz: usize,
    /// Width of the colour head's hidden layer (`n_hidden_neurons_dir`).
    pub n_hidden_neurons_dir: usize,
    /// Std of the Gaussian noise added to the raw density in training (`density_noise_std`);
    /// not a size: the model's parameters do not depend on it.
    pub density_noise_std: f64,
    /// Layers of the `mlp_xyz` trunk (`n_layers_xyz`, at least 1).
    pub n_layers_xyz: usize,
    /// Trunk layers before which the xyz embedding is concatenated again (`append_xyz`).
    pub append_xyz: Vec<usize>,
}

impl Default for NerfParams {
    /// The homework's defaults: 6 and 2 harmonics, widths 128 and 64, 6 layers, skip at 3, no
    /// density noise.
    fn default() -> Self {
        Self {
            n_harmonic_functions_xyz: 6,
            n_harmonic_functions_dir: 2,
            n_hidden_neurons_xyz: 128,
            n_hidden_neurons_dir: 64,
            n_layers_xyz: 6,
            append_xyz: vec![3],
            density_noise_std: 0.0,
        }
    }
}

/// `[sin(x·f), cos(x·f), x]` with `f = 2^0 … 2^(L−1)`, in pytorch3d's order (the fused
/// [`nerf_kernels::harmonic`] op, or its tensor-op twin).
///
/// `x`: `(M, 3)`; returns `(M, 3·2L + 3)`.
pub(crate) fn harmonic_embedding(x: &Tensor, n_harmonic_functions: usize) -> Result<Tensor> {
    Ok(nerf_kernels::harmonic::harmonic_embedding(
        x,
        n_harmonic_functions,
    )?)
}

/// Output width of [`harmonic_embedding`] for 3-D input.
pub(crate) fn embedding_dim(n_harmonic_functions: usize) -> usize {
    3 * 2 * n_harmonic_functions + 3
}

/// The density's activation, `relu(raw + noise)`, with Gaussian noise of standard deviation
/// `noise` (the homework's training regulariser; 0 = none).
///
/// `raw`: any shape; returns the same shape.
fn density_activation(raw: &Tensor, noise: f64) -> Result<Tensor> {
    let raw = match noise > 0.0 {
        true => (raw + raw.randn_like(0.0, noise)?)?,
        false => raw.clone(),
    };
    Ok(raw.relu()?)
}

/// `nn.Linear(in_dim, out_dim)` with PyTorch's default initialisation, under `vb`.
fn torch_linear(in_dim: usize, out_dim: usize, vb: VarBuilder) -> Result<Linear> {
    let bound = 1.0 / (in_dim as f64).sqrt();
    let init = Init::Uniform {
        lo: -bound,
        up: bound,
    };
    let w = vb.get_with_hints((out_dim, in_dim), "weight", init)?;
    let b = vb.get_with_hints(out_dim, "bias", init)?;
    Ok(Linear::new(w, Some(b)))
}

/// Input width of layer `i` of `mlp_xyz`: the xyz embedding for the first layer, hidden plus
/// the embedding where `append_xyz` concatenates it again, hidden otherwise.
pub(crate) fn mlp_input_dim(config: &NerfParams, i: usize) -> usize {
    let dim_xyz = embedding_dim(config.n_harmonic_functions_xyz);
    if i == 0 {
        dim_xyz
    } else if config.append_xyz.contains(&i) {
        config.n_hidden_neurons_xyz + dim_xyz
    } else {
        config.n_hidden_neurons_xyz
    }
}

/// The NeRF MLP.
#[derive(Debug, Clone)]
pub struct Nerf {
    /// The sizes the model was built with.
    pub config: NerfParams,
    mlp_xyz: Vec<Linear>,
    density_layer: Linear,
    intermediate_linear: Linear,
    color_layer_0: Linear,
    color_layer_2: Linear,
}

impl Nerf {
    /// Builds the model; parameters are created in (or loaded from) `vb`.
    pub fn new(config: &NerfParams, vb: VarBuilder) -> Result<Self> {
        let hidden = config.n_hidden_neurons_xyz;
        let dim_dir = embedding_dim(config.n_harmonic_functions_dir);
        ensure!(
            config.n_layers_xyz >= 1,
            "implicit_function.n_layers_xyz must be at least 1"
        );
        let mut mlp_xyz = Vec::with_capacity(config.n_layers_xyz);
        for i in 0..config.n_layers_xyz {
            mlp_xyz.push(torch_linear(
                mlp_input_dim(config, i),
                hidden,
                vb.pp(format!("mlp_xyz.mlp.{i}.0")),
            )?);
        }
        Ok(Self {
            config: config.clone(),
            mlp_xyz,
            density_layer: torch_linear(hidden, 1, vb.pp("density_layer.0"))?,
            intermediate_linear: torch_linear(hidden, hidden, vb.pp("intermediate_linear"))?,
            color_layer_0: torch_linear(
                hidden + dim_dir,
                config.n_hidden_neurons_dir,
                vb.pp("color_layer.0"),
            )?,
            color_layer_2: torch_linear(config.n_hidden_neurons_dir, 3, vb.pp("color_layer.2"))?,
        })
    }

    /// The layers as the fused MLP ([`nerf_kernels::nerf_mlp`]) takes them, and its shape.
    fn mlp_layers(&self) -> Result<(NerfLayers<'_>, NerfMlpShape)> {
        let hidden = self.config.n_hidden_neurons_xyz;
        let layers = NerfLayers {
            trunk: &self.mlp_xyz,
            density: &self.density_layer,
            feature: &self.intermediate_linear,
            colour_feature_weight: self.color_layer_0.weight().narrow(1, 0, hidden)?,
            colour_out: &self.color_layer_2,
        };
        let skip = (0..self.mlp_xyz.len())
            .map(|i| i > 0 && self.config.append_xyz.contains(&i))
            .collect();
        let shape = nerf_mlp::shape_of(&layers, skip)?;
        Ok((layers, shape))
    }

    /// The per-ray part of `color_layer.0` on `[features, dir_embedding]`:
    /// `W_d·dir_embedding + b`, computed once per ray (the MLP adds `W_f·features`).
    ///
    /// `directions`: `(N, 3)`; returns `(N, n_hidden_neurons_dir)`.
    fn colour_per_ray(&self, directions: &Tensor) -> Result<Tensor> {
        let hidden = self.config.n_hidden_neurons_xyz;
        let w = self.color_layer_0.weight();
        let w_dir = w.narrow(1, hidden, w.dim(1)? - hidden)?;
        let dir = harmonic_embedding(directions, self.config.n_harmonic_functions_dir)?;
        let per_ray = dir.matmul(&w_dir.t()?)?;
        Ok(match self.color_layer_0.bias() {
            Some(b) => per_ray.broadcast_add(b)?,
            None => per_ray,
        })
    }

    /// Density `(M, 1)` and colour `(M, 3)` at `points` `(M, 3)` whose rays are `ray_index`
    /// (`(M,)` u32, and the same values on the host) among `directions` `(N, 3)`.
    fn density_and_colour(
        &self,
        points: &Tensor,
        (ray_index, rays): (&Tensor, &[u32]),
        directions: &Tensor,
        density_noise: f64,
    ) -> Result<(Tensor, Tensor)> {
        let x = harmonic_embedding(points, self.config.n_harmonic_functions_xyz)?;
        let (layers, shape) = self.mlp_layers()?;
        let per_ray = self.colour_per_ray(directions)?;
        let out = nerf_mlp::mlp_forward(&x, &per_ray, (ray_index, rays), &layers, &shape)?;
        let density = density_activation(&out.narrow(1, 0, 1)?, density_noise)?;
        Ok((density, out.narrow(1, 1, 3)?))
    }

    /// Density and colour at every sample.
    ///
    /// `points`: `(N, S, 3)`; `directions`: `(N, 3)` unit vectors. Returns density `(N, S, 1)`
    /// (ReLU, ≥ 0) and colour `(N, S, 3)` (sigmoid, in (0, 1)). `density_noise` adds Gaussian
    /// noise of that standard deviation before the ReLU (training regulariser; 0 = off).
    pub fn forward(
        &self,
        points: &Tensor,
        directions: &Tensor,
        density_noise: f64,
    ) -> Result<FieldOutput> {
        FieldOutput::from_packed(points, |flat, rays| {
            self.density_and_colour(flat, rays, directions, density_noise)
        })
    }

    /// Density and colour at M samples drawn from N rays (only the samples worth evaluating).
    ///
    /// `points`: `(M, 3)`; `ray_index`: `(M,)` u32, the ray of each sample; `directions`:
    /// `(N, 3)` unit vectors. Returns density `(M, 1)` and colour `(M, 3)`, the same values
    /// [`Nerf::forward`] gives at those samples.
    pub(crate) fn forward_packed(
        &self,
        points: &Tensor,
        ray_index: &Tensor,
        directions: &Tensor,
        density_noise: f64,
    ) -> Result<(Tensor, Tensor)> {
        let rays = ray_index.to_vec1::<u32>()?;
        self.density_and_colour(points, (ray_index, &rays), directions, density_noise)
    }

    /// Density alone (no colour branch, no noise), as the occupancy grid needs it.
    ///
    /// `points`: `(M, 3)`; returns `(M, 1)`.
    pub(crate) fn density(&self, points: &Tensor) -> Result<Tensor> {
        let x = harmonic_embedding(points, self.config.n_harmonic_functions_xyz)?;
        let (layers, shape) = self.mlp_layers()?;
        Ok(nerf_mlp::density_forward(&x, &layers, &shape)?.relu()?)
    }

    /// The same model with weights detached from the autograd graph, for rendering: ops on it
    /// record nothing, so intermediate activations are freed as soon as they are used.
    pub(crate) fn detached(&self) -> Self {
        let detach = |l: &Linear| Linear::new(l.weight().detach(), l.bias().map(|b| b.detach()));
        Self {
            config: self.config.clone(),
            mlp_xyz: self.mlp_xyz.iter().map(detach).collect(),
            density_layer: detach(&self.density_layer),
            intermediate_linear: detach(&self.intermediate_linear),
            color_layer_0: detach(&self.color_layer_0),
            color_layer_2: detach(&self.color_layer_2),
        }
    }

    /// [`Nerf::forward`] on sampled rays: `samples.points` `(N, S, 3)`, `directions` `(N, 3)`;
    /// density `(N, S, 1)` and colour `(N, S, 3)`.
    pub(crate) fn evaluate(
        &self,
        samples: &RaySamples,
        directions: &Tensor,
        density_noise: f64,
    ) -> Result<FieldOutput> {
        self.forward(&samples.points, directions, density_noise)
    }
}

/// A NeRF as a field: the model and the training-time density noise (0 when rendering).
#[derive(Debug, Clone)]
pub struct NerfField {
    /// The NeRF MLP.
    pub model: Nerf,
    /// Standard deviation of the Gaussian noise added before the density ReLU (0 = off).
    pub density_noise: f64,
}

impl Field for NerfField {
    fn evaluate(
        &self,
        samples: &RaySamples,
        _deltas: &Tensor,
        directions: &Tensor,
    ) -> Result<FieldOutput> {
        self.model.evaluate(samples, directions, self.density_noise)
    }

    fn density(&self, points: &Tensor) -> Result<Tensor> {
        self.model.density(points)
    }

    fn fast_paths(&self) -> Option<&dyn FieldFastPaths> {
        Some(self)
    }
}

impl FieldFastPaths for NerfField {
    fn max_samples_per_chunk(&self) -> usize {
        // The fused MLP runs a chunk in 256-sample tasks, so the chunk bounds only the Candle
        // tensors around it (about 80 MiB at 2^17, the embedding the largest) and, when
        // training, the kept activations (about 4 KiB a sample). The homework's whole training
        // step runs in one chunk, faster than in smaller ones (docs/speed-and-report.md#allocators).
        1 << 17
    }

    fn supports_packed(&self) -> bool {
        true
    }

    fn evaluate_packed(
        &self,
        points: &Tensor,
        ray_index: &Tensor,
        directions: &Tensor,
    ) -> Result<(Tensor, Tensor)> {
        self.model
            .forward_packed(points, ray_index, directions, self.density_noise)
    }
}

/// `layer(x)` with the bias gradient summed in one pass ([`nerf_kernels::bias::bias_add`]).
///
/// `x`: `(M, in)`; returns `(M, out)`.
pub(crate) fn linear(layer: &Linear, x: &Tensor) -> Result<Tensor> {
    let pre = x.matmul(&layer.weight().t()?)?;
    Ok(match layer.bias() {
        Some(b) => nerf_kernels::bias::bias_add(&pre, b)?,
        None => pre,
    })
}

/// Shapes of every parameter, by PyTorch name, for a config (used to check checkpoints).
pub fn parameter_shapes(config: &NerfParams) -> Vec<(String, Vec<usize>)> {
    let hidden = config.n_hidden_neurons_xyz;
    let dim_dir = embedding_dim(config.n_harmonic_functions_dir);
    let mut out = Vec::new();
    let mut linear = |name: String, i: usize, o: usize| {
        out.push((format!("{name}.weight"), vec![o, i]));
        out.push((format!("{name}.bias"), vec![o]));
    };
    for i in 0..config.n_layers_xyz {
        linear(
            format!("mlp_xyz.mlp.{i}.0"),
            mlp_input_dim(config, i),
            hidden,
        );
    }
    linear("density_layer.0".into(), hidden, 1);
    linear("intermediate_linear".into(), hidden, hidden);
    linear(
        "color_layer.0".into(),
        hidden + dim_dir,
        config.n_hidden_neurons_dir,
    );
    linear("color_layer.2".into(), config.n_hidden_neurons_dir, 3);
    out
}

/// A NeRF with its parameters: the homework's model being trained or rendered.
pub struct NerfState {
    /// The model's variables by PyTorch name.
    pub varmap: VarMap,
    /// The model, built on `varmap`.
    pub model: Nerf,
}

impl NerfState {
    /// A freshly initialised model: PyTorch's default `nn.Linear` init, U(−1/√fan_in,
    /// 1/√fan_in) for weights and biases, drawn from a generator seeded with `seed` (parameters
    /// in name order), so runs are reproducible.
    pub fn seeded(params: &NerfParams, seed: u64, device: &Device) -> Result<Self> {
        let varmap = VarMap::new();
        let model = Nerf::new(params, VarBuilder::from_varmap(&varmap, DType::F32, device))?;
        seed_uniform(&varmap, seed, linear_init_bound, device)?;
        Ok(Self { varmap, model })
    }

    /// The model of `params` with the parameters in `tensors` (a checkpoint's, by PyTorch
    /// name; names and shapes checked, the error naming `origin`).
    pub fn from_tensors(
        params: &NerfParams,
        tensors: &std::collections::HashMap<String, Tensor>,
        origin: &std::path::Path,
    ) -> Result<Self> {
        let state = Self::new(params, &Device::Cpu)?;
        load_parameters(
            &state.varmap,
            &parameter_shapes(params),
            tensors,
            KIND,
            origin,
        )?;
        Ok(state)
    }

    /// [`NerfState::seeded`] with seed 0.
    pub fn new(params: &NerfParams, device: &Device) -> Result<Self> {
        Self::seeded(params, 0, device)
    }

    /// The field for training: the model's weights as variables (gradients reach them) with
    /// `density_noise`.
    pub fn training_field(&self, density_noise: f64) -> NerfField {
        NerfField {
            model: self.model.clone(),
            density_noise,
        }
    }

    /// The field for rendering: detached weights (no gradient graph), no density noise.
    pub fn field(&self) -> NerfField {
        NerfField {
            model: self.model.detached(),
            density_noise: 0.0,
        }
    }
}

impl FieldSpec for NerfParams {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn seeded(&self, seed: u64, device: &Device) -> Result<Box<dyn TrainableField>> {
        Ok(Box::new(NerfState::seeded(self, seed, device)?))
    }

    fn parameter_shapes(&self) -> Result<ParameterShapes> {
        Ok(parameter_shapes(self))
    }
}

impl TrainableField for NerfState {
    fn kind(&self) -> &'static str {
        KIND
    }

    fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    /// PyTorch's module order, which the homework's checkpoints index their optimiser by.
    fn parameter_shapes(&self) -> ParameterShapes {
        parameter_shapes(&self.model.config)
    }

    fn training_field(&self, density_noise: f64) -> BoxedField {
        Box::new(NerfState::training_field(self, density_noise))
    }

    fn render_field(&self) -> BoxedField {
        Box::new(self.field())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device, Module};
    use candle_nn::VarMap;

    fn homework_config() -> NerfParams {
        NerfParams::default()
    }

    #[test]
    fn embedding_matches_pytorch3d_ordering() {
        let x = Tensor::new(&[[0.5f32, -1.0, 2.0]], &Device::Cpu).unwrap();
        let e = harmonic_embedding(&x, 2).unwrap().to_vec2::<f32>().unwrap()[0].clone();
        assert_eq!(e.len(), embedding_dim(2));
        // embed = [x0·1, x0·2, x1·1, x1·2, x2·1, x2·2]; then sin, cos, x.
        let embed = [0.5f32, 1.0, -1.0, -2.0, 2.0, 4.0];
        for k in 0..6 {
            assert!((e[k] - embed[k].sin()).abs() < 1e-6);
            assert!((e[6 + k] - embed[k].cos()).abs() < 1e-6);
        }
        assert_eq!(&e[12..], &[0.5, -1.0, 2.0]);
    }

    #[test]
    fn shapes_names_and_ranges() {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let cfg = homework_config();
        let model = Nerf::new(&cfg, vb).unwrap();
        let points = Tensor::randn(0f32, 1.0, (5, 7, 3), &Device::Cpu).unwrap();
        let dirs = Tensor::randn(0f32, 1.0, (5, 3), &Device::Cpu).unwrap();
        let out = model.forward(&points, &dirs, 0.0).unwrap();
        assert_eq!(out.density.dims(), &[5, 7, 1]);
        assert_eq!(out.feature.dims(), &[5, 7, 3]);
        let d = out.density.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert!(d.iter().all(|v| *v >= 0.0));
        let c = out.feature.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert!(c.iter().all(|v| *v > 0.0 && *v < 1.0));
        let data = varmap.data().lock().unwrap();
        let expected = parameter_shapes(&cfg);
        assert_eq!(data.len(), expected.len());
        for (name, shape) in expected {
            assert_eq!(data[&name].dims(), &shape[..], "{name}");
        }
        // The homework-size model: about 0.5 MB of f32 parameters.
        let n: usize = data.values().map(|v| v.elem_count()).sum();
        assert!((100_000..150_000).contains(&n), "{n} parameters");
    }

    #[test]
    fn per_ray_direction_branch_equals_concatenation() {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
        let cfg = NerfParams {
            n_hidden_neurons_xyz: 16,
            n_hidden_neurons_dir: 8,
            n_layers_xyz: 3,
            append_xyz: vec![2],
            ..homework_config()
        };
        let model = Nerf::new(&cfg, vb).unwrap();
        let points = Tensor::randn(0f32, 1.0, (4, 3, 3), &Device::Cpu).unwrap();
        let dirs = Tensor::randn(0f32, 1.0, (4, 3), &Device::Cpu).unwrap();
        let fast = model.forward(&points, &dirs, 0.0).unwrap().feature;
        // Straightforward version: concatenate the direction embedding to every sample.
        let xyz = harmonic_embedding(&points.reshape((12, 3)).unwrap(), 6).unwrap();
        let mut y = xyz.clone();
        for (i, l) in model.mlp_xyz.iter().enumerate() {
            if i == 2 {
                y = Tensor::cat(&[&y, &xyz], 1).unwrap();
            }
            y = l.forward(&y).unwrap().relu().unwrap();
        }
        let f = model.intermediate_linear.forward(&y).unwrap();
        let dir = harmonic_embedding(&dirs, 2).unwrap();
        let dir = dir
            .unsqueeze(1)
            .unwrap()
            .broadcast_as((4, 3, 15))
            .unwrap()
            .reshape((12, 15))
            .unwrap();
        let h = model
            .color_layer_0
            .forward(&Tensor::cat(&[&f, &dir], 1).unwrap())
            .unwrap()
            .relu()
            .unwrap();
        let slow = candle_nn::ops::sigmoid(&model.color_layer_2.forward(&h).unwrap())
            .unwrap()
            .reshape((4, 3, 3))
            .unwrap();
        let diff = nerf_core::compare::max_abs_difference(&fast, &slow).unwrap();
        assert!(diff < 1e-6, "{diff}");
    }
}
