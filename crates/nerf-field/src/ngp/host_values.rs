//! The hash-grid field evaluated on host buffers through the fused kernels, with no Candle op
//! over the samples: the box mapping, the encoding and the MLPs (or the density MLP alone)
//! as plain passes. What the fused training step ([`super::fused_step`]) runs forward, and
//! the occupancy grid's probe. Its twin is the same field through Candle ops
//! ([`Ngp::forward_packed`] and [`Ngp::density`]).

use anyhow::{bail, Result};
use candle_core::{Layout, Storage};

use super::{Ngp, GEO_FEATURES, HIDDEN};
use nerf_hash_grid::box_unit::box_unit_values;
use nerf_hash_grid::hash_grid::encode_values;
use nerf_hash_grid::ngp_mlp::{mlp_values, pack_parameters, raw_density_values, MlpShape};
use nerf_kernels::storage::contiguous_f32;

/// The field's values at samples, on host buffers.
pub(super) struct HostValues {
    /// Points in the box's unit cube, 3 values each (the encoding's input).
    pub(super) unit: Vec<f32>,
    /// 1 inside the box, 0 outside.
    pub(super) inside: Vec<f32>,
    /// The encoding, `L·F` values each.
    pub(super) encoding: Vec<f32>,
    /// `[raw density, r, g, b]` each ([`mlp_values`]).
    pub(super) out: Vec<f32>,
}

/// The table's values in its CPU `storage` (contiguous f32), or an error off the CPU.
pub(super) fn table_values<'a>(storage: &'a Storage, layout: &Layout) -> Result<&'a [f32]> {
    let Storage::Cpu(cpu) = storage else {
        bail!("the hash-grid field on host buffers needs its table on the CPU");
    };
    Ok(contiguous_f32(cpu, layout, "hash-grid field")?)
}

impl Ngp {
    /// The MLPs' widths, for the fused MLP kernel.
    pub(super) fn mlp_shape(&self) -> MlpShape {
        MlpShape {
            enc: self.grid.output_dim(),
            hidden: HIDDEN,
            geo: GEO_FEATURES,
        }
    }

    /// The MLPs' parameters, packed in [`MlpShape`]'s order, as host values.
    pub(super) fn packed_mlp_values(&self) -> Result<Vec<f32>> {
        let bias = |l: &candle_nn::Linear| l.bias().cloned().expect("NGP layers have biases");
        let wg = self.color[0].weight().narrow(1, 0, GEO_FEATURES)?;
        let packed = pack_parameters(
            self.density[0].weight(),
            &bias(&self.density[0]),
            self.density[1].weight(),
            &bias(&self.density[1]),
            &wg,
            [
                self.color[1].weight(),
                &bias(&self.color[1]),
                self.color[2].weight(),
                &bias(&self.color[2]),
            ],
        )?;
        Ok(packed.detach().to_vec1::<f32>()?)
    }

    /// σ `(M)` at world `points` `(M, 3)` (row-major host values), detached: the density of
    /// [`Ngp::density`] through the fused kernels on host buffers, the encoding and the
    /// density MLP only (what the occupancy grid probes, ~2^18 points an update).
    pub(crate) fn density_values(&self, points: &[f32]) -> Result<Vec<f32>> {
        let (storage, layout) = self.table.storage_and_layout();
        let table = table_values(&storage, layout)?;
        let (unit, inside) = self.unit_points(points.to_vec());
        let encoding = encode_values(&self.grid, table, &unit);
        drop(storage);
        let raw = raw_density_values(self.mlp_shape(), &encoding, &self.packed_mlp_values()?);
        let activation = self.params.density_activation;
        Ok(raw
            .iter()
            .zip(&inside)
            .map(|(&x, i)| activation.value(x) * i)
            .collect())
    }

    /// World `points` (3 values each) contracted and mapped to the box's unit cube, and 1
    /// where they lie in it, else 0 ([`box_unit_values`]).
    fn unit_points(&self, mut points: Vec<f32>) -> (Vec<f32>, Vec<f32>) {
        let contraction = self.params.contraction;
        if contraction != nerf_core::contraction::Contraction::None {
            for p in points.chunks_exact_mut(3) {
                p.copy_from_slice(&contraction.contract_f32([p[0], p[1], p[2]]));
            }
        }
        let [lo, hi] = self.params.aabb;
        let scale: [f32; 3] = std::array::from_fn(|k| 1.0 / (hi[k] - lo[k]) as f32);
        box_unit_values(&points, lo.map(|v| v as f32), scale)
    }

    /// The field at world `points` (3 values each) on rays `rays` (one each) whose per-ray
    /// colour term is in `per_ray` `(N, H)`, with the `table` values and the packed MLP
    /// `params` ([`Ngp::packed_mlp_values`]).
    pub(super) fn evaluate_on_host(
        &self,
        (table, params): (&[f32], &[f32]),
        points: Vec<f32>,
        (rays, per_ray): (&[u32], &[f32]),
    ) -> HostValues {
        let (unit, inside) = self.unit_points(points);
        let encoding = encode_values(&self.grid, table, &unit);
        let out = mlp_values(self.mlp_shape(), &encoding, (rays, per_ray), params);
        HostValues {
            unit,
            inside,
            encoding,
            out,
        }
    }
}
