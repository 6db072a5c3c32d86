//! The `implicit_function` section at run time: the field kind it describes, as the library's
//! [`FieldSpec`] or [`SdfVolume`], and trained models loaded for it. Each kind's own config
//! says what it becomes ([`nerf_field::registry`]); everything else asks
//! [`Config::field_spec`] and [`Config::load_model`], and sees only the seam's traits.

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Result};
use candle_core::Device;

use super::messages::plural;
use super::Config;
use nerf_checkpoint::checkpoint::CheckpointInfo;
use nerf_core::sdf::SdfVolume;
use nerf_field::nerf::NerfParams;
use nerf_field::registry::kind_names;
use nerf_field::sdf::{SdfField, SdfModel, SdfTrainable};
use nerf_field::sdf_config::SdfVolumeConfig;
use nerf_field::trainable::{BoxedField, FieldSpec};
use nerf_train::model::TrainModel;

impl Config {
    /// How the field maps world points into its grid's space (identity but for an `ngp` field
    /// with `contraction: linf`); the occupancy grid tests points in the same space.
    pub(crate) fn contraction(&self) -> nerf_core::contraction::Contraction {
        self.implicit_function.field().contraction()
    }

    /// Fits a hash-grid field (`ngp`) and the occupancy grid to `cube` (`[min x, y, z, max x,
    /// y, z]` in the normalised frame), with no scene contraction: the form of a model of an
    /// object photographed alone, which holds nothing outside the cube
    /// ([`nerf_scene::dataset::object_hull::object_fit`]). Returns false, changing nothing,
    /// for another field kind.
    pub fn fit_to_object(&mut self, cube: [f64; 6]) -> bool {
        use nerf_core::contraction::Contraction;
        use nerf_field::ngp::NgpParams;
        let Some(ngp) = self.implicit_function.get_mut::<NgpParams>() else {
            return false;
        };
        ngp.aabb = [[cube[0], cube[1], cube[2]], [cube[3], cube[4], cube[5]]];
        ngp.contraction = Contraction::None;
        if let Some(grid) = self.renderer.occupancy_grid.as_mut() {
            grid.aabb = cube;
        }
        true
    }

    /// The NeRF's sizes, or an error naming the key when the config describes another field.
    pub fn nerf_params(&self) -> Result<NerfParams> {
        match self.implicit_function.get::<NerfParams>() {
            Some(n) => Ok(n.clone()),
            None => bail!(
                "implicit_function.type is {}: these are the NeRF MLP's sizes, for a nerf config such as lego (Config::field_spec gives any trainable kind)",
                self.implicit_function.kind()
            ),
        }
    }

    /// The SDF volume's config, or an error naming the key for another kind.
    fn sdf_volume_config(&self) -> Result<&SdfVolumeConfig> {
        match self.implicit_function.get::<SdfVolumeConfig>() {
            Some(s) => Ok(s),
            None => bail!("implicit_function.type: this command needs sdf_volume"),
        }
    }

    /// The SDF volume's initial values, when the config describes one.
    pub fn sdf_volume(&self) -> Result<SdfVolume> {
        self.sdf_volume_config()?.volume()
    }

    /// Which SDF parameters the config marks `opt: True`. An error names an `opt: True` on
    /// a parameter the shape does not have (a box's `radius`, a sphere's `side_lengths`).
    pub(crate) fn sdf_trainable(&self) -> Result<SdfTrainable> {
        self.sdf_volume_config()?.trainable()
    }

    /// The SDF volume as a model to fit: its `opt: True` parameters as variables.
    pub fn sdf_model(&self, device: &Device) -> Result<SdfModel> {
        SdfModel::new(&self.sdf_volume()?, self.sdf_trainable()?, device)
    }

    /// The SDF volume as a field for rendering (every parameter constant).
    pub fn sdf_field(&self, device: &Device) -> Result<SdfField> {
        SdfField::fixed(&self.sdf_volume()?, device)
    }

    /// The trainable field the config describes (its kind and sizes); an error for an SDF
    /// volume.
    pub fn field_spec(&self) -> Result<Arc<dyn FieldSpec>> {
        match self.implicit_function.field().field_spec() {
            Some(spec) => spec,
            None => bail!(
                "implicit_function.type: this command needs {}",
                kind_names(true)
            ),
        }
    }

    /// The standard deviation of the noise the NeRF MLP adds to its raw density in training
    /// (`density_noise_std`; 0 for the other kinds).
    pub(crate) fn density_noise(&self) -> f64 {
        self.implicit_function.field().density_noise()
    }

    /// A trained field for rendering or evaluating with this config, whatever its kind:
    /// weights from the checkpoint at `path` and the occupancy grid the config asks for.
    pub fn load_field(&self, path: &Path, device: &Device) -> Result<BoxedField> {
        Ok(self.load_model(path, device)?.0.render_field())
    }

    /// A trained model for rendering with this config, whatever its kind: weights from the
    /// checkpoint at `path` (names and shapes checked, any float dtype), and the occupancy grid
    /// the config asks for (the checkpoint's, or one built from the model). Says on stderr
    /// which file it loaded and at which epoch.
    pub fn load_model(&self, path: &Path, device: &Device) -> Result<(TrainModel, CheckpointInfo)> {
        self.ensure_checkpoint(path)?;
        let (state, info) = TrainModel::load(
            &*self.field_spec()?,
            self.occupancy_grid().as_ref(),
            path,
            device,
        )?;
        nerf_core::term::note(&format!(
            "loaded {} (epoch {}, {} Adam {})",
            path.display(),
            info.epoch,
            info.adam_step,
            plural(info.adam_step as usize, "step", "steps")
        ));
        if state
            .occupancy
            .as_ref()
            .is_some_and(|g| !g.any_dense_cell())
        {
            nerf_core::term::note(
                "warning: the occupancy grid has no occupied cell: the model has no density above \
                 the grid's threshold anywhere, so every render is empty",
            );
        }
        Ok((state, info))
    }
}

#[cfg(test)]
mod tests {
    use crate::Config;
    use nerf_field::ngp::NgpParams;

    /// The built-in lego config's text with its `implicit_function` section's body replaced
    /// by `body` (indented lines).
    fn yaml(body: &str) -> String {
        let lego = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../configs/lego.yaml"
        ))
        .unwrap();
        let start = lego.find("implicit_function:").unwrap();
        let end = lego.find("cameras:").unwrap();
        format!(
            "{}implicit_function:\n{body}\n{}",
            &lego[..start],
            &lego[end..]
        )
    }

    #[test]
    fn a_hash_grid_is_fitted_to_an_object_and_a_nerf_is_left_alone() {
        use nerf_core::contraction::Contraction;
        let mut c = Config::load("nerf_scene", &[]).unwrap();
        assert_eq!(c.contraction(), Contraction::LInf);
        let cube = [-0.25, -0.5, -0.125, 0.5, 0.25, 0.625];
        assert!(c.fit_to_object(cube));
        let n = c.implicit_function.get::<NgpParams>().expect("ngp");
        assert_eq!(n.aabb, [[-0.25, -0.5, -0.125], [0.5, 0.25, 0.625]]);
        assert_eq!(c.contraction(), Contraction::None);
        assert_eq!(c.renderer.occupancy_grid.as_ref().unwrap().aabb, cube);
        let mut nerf = Config::load("nerf_lego", &[]).unwrap();
        let before = nerf.clone();
        assert!(!nerf.fit_to_object(cube));
        assert_eq!(nerf, before);
    }

    #[test]
    fn ngp_keys_and_defaults() {
        let c = Config::from_yaml(&yaml("  type: ngp"), &[]).unwrap();
        let n = c.implicit_function.get::<NgpParams>().expect("ngp");
        let p = n.grid();
        assert_eq!((p.n_levels, p.n_features, p.log2_table_size), (16, 2, 19));
        assert_eq!((p.base_resolution, p.max_resolution), (16.0, 3072.0));
        assert_eq!(n.aabb, [[-1.5; 3], [1.5; 3]]);
        let o = vec!["implicit_function.log2_hashmap_size=12".to_string()];
        let c = Config::from_yaml(&yaml("  type: ngp\n  max_resolution: 512"), &o).unwrap();
        let n = c.implicit_function.get::<NgpParams>().expect("ngp");
        assert_eq!(n.grid().max_resolution, 512.0);
        assert_eq!(n.grid().log2_table_size, 12);
        assert!(c.nerf_params().unwrap_err().to_string().contains("ngp"));
        for bad in [
            "  type: ngp\n  density_activation: relu",
            "  type: ngp\n  log2_hashmap_size: 30",
            "  type: ngp\n  aabb: [[1, 1, 1], [0, 2, 2]]",
            "  type: ngp\n  n_hidden: 3",
        ] {
            let e = Config::from_yaml(&yaml(bad), &[]).unwrap_err().to_string();
            assert!(!e.contains('\n'), "{e}");
        }
        // Unknown names are refused in the words of the key and the names it takes.
        let e = Config::from_yaml(&yaml("  type: ngp\n  density_activation: relu"), &[]);
        assert_eq!(
            e.unwrap_err().to_string(),
            "implicit_function.density_activation: unknown `relu` (expected trunc_exp or softplus)"
        );
        let e = Config::from_yaml(&yaml("  type: mesh"), &[]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "implicit_function.type: unknown type `mesh` (expected sdf_volume, nerf or ngp)"
        );
        let e = Config::from_yaml(&yaml("  n_layers_xyz: 3"), &[]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "implicit_function.type: missing (sdf_volume, nerf or ngp)"
        );
    }

    #[test]
    fn an_ngp_checkpoint_saves_and_loads_for_rendering() {
        use nerf_field::ngp::Ngp;
        let body = "  type: ngp\n  n_levels: 4\n  log2_hashmap_size: 10\n  max_resolution: 64";
        let c = Config::from_yaml(&yaml(body), &[]).unwrap();
        let n = c.implicit_function.get::<NgpParams>().expect("ngp");
        let dev = candle_core::Device::Cpu;
        let varmap = candle_nn::VarMap::new();
        let vb = candle_nn::VarBuilder::from_varmap(&varmap, candle_core::DType::F32, &dev);
        let model = Ngp::new(n, vb).unwrap();
        let (_dir, path) = nerf_files::test_files::temp_file("ngp.safetensors");
        let tensors = nerf_checkpoint::checkpoint::model_tensors(&varmap);
        nerf_checkpoint::checkpoint::save(&path, &tensors, Default::default()).unwrap();
        let field = c.load_field(&path, &dev).unwrap();
        assert!(nerf_render::field::supports_packed(field.as_ref()) && field.occupancy().is_some());
        let points = candle_core::Tensor::rand(-1.4f32, 1.4, (50, 3), &dev).unwrap();
        let dirs = candle_core::Tensor::new(&[[0f32, 0.6, 0.8]], &dev).unwrap();
        let rays = candle_core::Tensor::zeros(50, candle_core::DType::U32, &dev).unwrap();
        let (s0, c0) = model.forward_packed(&points, &rays, &dirs, None).unwrap();
        let (s1, c1) =
            nerf_render::field::packed_evaluation(field.as_ref(), &points, &rays, &dirs).unwrap();
        let diff = nerf_core::compare::max_abs_difference;
        assert_eq!(diff(&s0, &s1).unwrap() + diff(&c0, &c1).unwrap(), 0.0);
        // A checkpoint of other sizes is refused in one line.
        let o = vec!["implicit_function.log2_hashmap_size=11".to_string()];
        let other = Config::from_yaml(&yaml(body), &o).unwrap();
        let e = format!("{:#}", other.load_field(&path, &dev).err().unwrap());
        assert!(e.contains("encoding.table") || e.contains("shape"), "{e}");
    }
}
