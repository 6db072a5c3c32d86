//! Adam exactly as `torch.optim.Adam` (no weight decay), with state that can be saved and
//! restored so a resumed run continues the same optimisation.

use std::collections::HashMap;

use anyhow::{Context, Result};
use candle_core::backprop::GradStore;
use candle_core::{Tensor, Var};

/// Adam's hyper-parameters and per-parameter moments.
pub struct Adam {
    /// Learning rate (set per epoch by the training schedule).
    pub lr: f64,
    /// Decay of the first-moment running average (PyTorch's `betas[0]`, default 0.9).
    pub beta1: f64,
    /// Decay of the second-moment running average (PyTorch's `betas[1]`, default 0.999).
    pub beta2: f64,
    /// Term added to the denominator for stability (default 1e-8).
    pub eps: f64,
    /// Number of steps taken.
    pub step: u64,
    /// Parameters by name, in a fixed order.
    params: Vec<(String, Var)>,
    /// First and second moments by parameter name (`exp_avg`, `exp_avg_sq` in PyTorch).
    moments: HashMap<String, (Tensor, Tensor)>,
}

impl Adam {
    /// Adam on a field's dense parameters with the group's constants
    /// ([`nerf_field::trainable::DenseGroup`]).
    pub(crate) fn for_group(group: nerf_field::trainable::DenseGroup, lr: f64) -> Result<Self> {
        let mut adam = Self::new(group.vars, lr)?;
        (adam.beta2, adam.eps) = (group.beta2, group.eps);
        Ok(adam)
    }

    /// PyTorch's defaults: betas (0.9, 0.999), eps 1e-8.
    pub fn new(params: Vec<(String, Var)>, lr: f64) -> Result<Self> {
        let mut moments = HashMap::new();
        for (name, var) in &params {
            moments.insert(name.clone(), (var.zeros_like()?, var.zeros_like()?));
        }
        Ok(Self {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            step: 0,
            params,
            moments,
        })
    }

    /// One update from `grads`; parameters without a gradient are left alone.
    pub fn step(&mut self, grads: &GradStore) -> Result<()> {
        self.step += 1;
        let t = self.step as i32;
        let bias1 = 1.0 - self.beta1.powi(t);
        let bias2 = 1.0 - self.beta2.powi(t);
        for (name, var) in &self.params {
            let Some(g) = grads.get(var.as_tensor()) else {
                continue;
            };
            let (m, v) = self.moments.get_mut(name).context("missing Adam state")?;
            *m = ((m.clone() * self.beta1)? + (g * (1.0 - self.beta1))?)?;
            *v = ((v.clone() * self.beta2)? + (g.sqr()? * (1.0 - self.beta2))?)?;
            // PyTorch: denom = sqrt(v)/sqrt(bias2) + eps; p -= lr/bias1 · m/denom.
            let denom = ((v.sqrt()? / bias2.sqrt())? + self.eps)?;
            let update = (m.div(&denom)? * (self.lr / bias1))?;
            var.set(&var.as_tensor().sub(&update)?)?;
        }
        Ok(())
    }

    /// State tensors by name: `adam.exp_avg.<param>` and `adam.exp_avg_sq.<param>`, each of
    /// its parameter's shape.
    pub(crate) fn state_tensors(&self) -> Vec<(String, Tensor)> {
        let mut out = Vec::new();
        for (name, _) in &self.params {
            let (m, v) = &self.moments[name];
            out.push((format!("adam.exp_avg.{name}"), m.clone()));
            out.push((format!("adam.exp_avg_sq.{name}"), v.clone()));
        }
        out
    }

    /// Restores moments (from [`Adam::state_tensors`] names, each of its parameter's shape;
    /// an error names a missing or misshapen one) and the step count.
    pub(crate) fn load_state(
        &mut self,
        tensors: &HashMap<String, Tensor>,
        step: u64,
    ) -> Result<()> {
        for (name, var) in &self.params {
            let get = |key: String| -> Result<Tensor> {
                let t = tensors
                    .get(&key)
                    .with_context(|| format!("checkpoint lacks optimizer tensor {key}"))?;
                anyhow::ensure!(
                    t.dims() == var.dims(),
                    "checkpoint tensor {key} has shape {:?}, the model needs {:?}",
                    t.dims(),
                    var.dims()
                );
                Ok(t.to_device(var.device())?)
            };
            let m = get(format!("adam.exp_avg.{name}"))?;
            let v = get(format!("adam.exp_avg_sq.{name}"))?;
            self.moments.insert(name.clone(), (m, v));
        }
        self.step = step;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    /// One Adam step on the loss (p − 3)².
    fn step_towards_three(adam: &mut Adam, p: &Var) {
        let loss = p
            .as_tensor()
            .affine(1.0, -3.0)
            .unwrap()
            .sqr()
            .unwrap()
            .sum_all()
            .unwrap();
        adam.step(&loss.backward().unwrap()).unwrap();
    }

    #[test]
    fn matches_hand_computed_pytorch_steps() {
        // Minimise (p − 3)² from p = 0 with lr 0.1: PyTorch's first step moves by exactly lr.
        let p = Var::new(&[0f32], &Device::Cpu).unwrap();
        let mut adam = Adam::new(vec![("p".into(), p.clone())], 0.1).unwrap();
        step_towards_three(&mut adam, &p);
        let v = p.as_tensor().to_vec1::<f32>().unwrap()[0];
        assert!((v - 0.1).abs() < 1e-6, "{v}");
        // Second step by hand: g1 = −6, g2 = 2(0.1 − 3) = −5.8.
        step_towards_three(&mut adam, &p);
        let (g1, g2) = (-6.0f64, -5.8f64);
        let m = 0.9 * (0.1 * g1) + 0.1 * g2;
        let v2 = 0.999 * (0.001 * g1 * g1) + 0.001 * g2 * g2;
        let expected =
            0.1 - 0.1 / (1.0 - 0.81) * m / (v2.sqrt() / (1.0f64 - 0.998001).sqrt() + 1e-8);
        let got = p.as_tensor().to_vec1::<f32>().unwrap()[0] as f64;
        assert!((got - expected).abs() < 1e-6, "{got} vs {expected}");
    }

    #[test]
    fn state_round_trips() {
        let p = Var::new(&[1f32, 2.0], &Device::Cpu).unwrap();
        let mut a = Adam::new(vec![("w".into(), p.clone())], 0.01).unwrap();
        let loss = p.as_tensor().sqr().unwrap().sum_all().unwrap();
        a.step(&loss.backward().unwrap()).unwrap();
        let saved: HashMap<String, Tensor> = a.state_tensors().into_iter().collect();
        let mut b = Adam::new(vec![("w".into(), p.clone())], 0.01).unwrap();
        b.load_state(&saved, a.step).unwrap();
        assert_eq!(b.step, 1);
        assert_eq!(
            b.state_tensors()[0].1.to_vec1::<f32>().unwrap(),
            saved["adam.exp_avg.w"].to_vec1::<f32>().unwrap()
        );
    }
}
