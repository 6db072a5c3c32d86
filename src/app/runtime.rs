//! A parsed [`Config`] turned into the library's plain parameters: sampler, renderer, cameras,
//! fields, occupancy grid and training settings. The only place below `main.rs` where config
//! sections become runtime objects.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use candle_core::Device;
use glam::DVec3;

use crate::app::config::{Config, ImplicitFunctionConfig, NerfConfig, SdfKind, TrainingConfig};
use crate::core::camera::{look_at_view_transform, surround_cameras, PerspectiveCamera};
use crate::core::sdf::{Sdf, SdfVolume};
use crate::field::nerf::NerfParams;
use crate::field::sdf::{SdfField, SdfTrainable};
use crate::field::trainable::FieldSpec;
use crate::io::checkpoint::CheckpointInfo;
use crate::render::hierarchical::CoarseToFineSampler;
use crate::render::occupancy::{density_threshold, OccupancyGridParams};
use crate::render::ray_sampler::RaySampler;
use crate::render::renderer::VolumeRenderer;
use crate::render::sampler::StratifiedSampler;
use crate::train::fit::{GridSchedule, TrainPaths, TrainSettings};
use crate::train::fit_sdf::SdfFitSettings;
use crate::train::model::TrainModel;
use crate::train::step::StepSettings;

/// The NeRF shipped with the project, the default of every command that loads a model when
/// neither `--checkpoint` nor the config's `training.checkpoint_path` names one.
pub const SHIPPED_CHECKPOINT: &str = "checkpoints/nerf_lego.safetensors";

/// The lego NeRF trained as the homework trains it (`nerf_lego`, dense sampling, no occupancy
/// grid): the shipped model for configs that render densely.
pub const HOMEWORK_CHECKPOINT: &str = "checkpoints/homework/nerf_lego.safetensors";

/// The shipped hash-grid lego model (the `lego_ngp` config's checkpoint).
pub const SHIPPED_NGP_CHECKPOINT: &str = "checkpoints/ngp_lego.safetensors";

/// `one` or `many` by `n`.
pub fn plural<'a>(n: usize, one: &'a str, many: &'a str) -> &'a str {
    if n == 1 {
        one
    } else {
        many
    }
}

impl NerfConfig {
    /// The model's sizes.
    pub fn params(&self) -> NerfParams {
        NerfParams {
            n_harmonic_functions_xyz: self.n_harmonic_functions_xyz,
            n_harmonic_functions_dir: self.n_harmonic_functions_dir,
            n_hidden_neurons_xyz: self.n_hidden_neurons_xyz,
            n_hidden_neurons_dir: self.n_hidden_neurons_dir,
            n_layers_xyz: self.n_layers_xyz,
            append_xyz: self.append_xyz.clone(),
        }
    }
}

impl Config {
    /// Image width and height.
    pub fn image_size(&self) -> (usize, usize) {
        (self.data.image_size[0], self.data.image_size[1])
    }

    /// The `sampler` section as a sampler: stratified, or coarse-to-fine when
    /// `n_pts_per_ray_fine` > 0.
    pub fn sampler(&self) -> Result<std::sync::Arc<dyn RaySampler>> {
        let stratified = self.stratified_sampler()?;
        Ok(match self.sampler.n_pts_per_ray_fine {
            0 => std::sync::Arc::new(stratified),
            n_fine => std::sync::Arc::new(CoarseToFineSampler {
                coarse: stratified,
                n_fine,
            }),
        })
    }

    /// The `sampler` section's stratified depths alone (the SDF fit and the float64 reference
    /// sample only these).
    pub fn stratified_sampler(&self) -> Result<StratifiedSampler> {
        StratifiedSampler::new(
            self.sampler.n_pts_per_ray,
            self.sampler.min_depth,
            self.sampler.max_depth,
        )
    }

    /// The `renderer` section as a renderer: chunk size, background, early termination (the
    /// occupancy grid belongs to the field; see [`Config::occupancy_grid`]).
    pub fn renderer(&self) -> Result<VolumeRenderer> {
        VolumeRenderer::new(self.renderer.chunk_size, self.renderer.white_background)?
            .with_early_termination(self.renderer.early_termination)
    }

    /// The surround cameras of the `cameras` section.
    pub fn surround_cameras(&self) -> Vec<PerspectiveCamera> {
        let c = &self.cameras;
        surround_cameras(c.radius, c.n_poses, DVec3::from_array(c.up), c.focal_length)
    }

    /// The trainable field the config describes (its kind and sizes), or an error naming the
    /// key when it describes an SDF volume.
    pub fn field_spec(&self) -> Result<std::sync::Arc<dyn FieldSpec>> {
        Ok(match &self.implicit_function {
            ImplicitFunctionConfig::Nerf(n) => std::sync::Arc::new(n.params()),
            ImplicitFunctionConfig::Ngp(n) => std::sync::Arc::new(n.params()?),
            ImplicitFunctionConfig::SdfVolume(_) => {
                bail!("implicit_function.type: this command needs nerf or ngp")
            }
        })
    }

    /// The NeRF's sizes, or an error naming the key when the config describes another field.
    pub fn nerf_params(&self) -> Result<NerfParams> {
        match &self.implicit_function {
            ImplicitFunctionConfig::Nerf(n) => Ok(n.params()),
            ImplicitFunctionConfig::Ngp(_) => bail!(
                "implicit_function.type is ngp: this command takes nerf configs only so far (training ngp is not wired in yet, issue 13); render and eval take ngp"
            ),
            ImplicitFunctionConfig::SdfVolume(_) => bail!(
                "implicit_function.type is sdf_volume: this command needs a NeRF config (e.g. lego)"
            ),
        }
    }

    /// The SDF volume's initial values, when the config describes one.
    pub fn sdf_volume(&self) -> Result<SdfVolume> {
        let ImplicitFunctionConfig::SdfVolume(s) = &self.implicit_function else {
            bail!("implicit_function.type: this command needs sdf_volume");
        };
        let center = s.sdf.center.val.map(|v| v as f32);
        // Validation guarantees the shape's own key is present.
        let sdf = match (s.sdf.kind, &s.sdf.side_lengths, &s.sdf.radius) {
            (SdfKind::Box, Some(sides), _) => Sdf::Box {
                center,
                side_lengths: sides.val.map(|v| v as f32),
            },
            (SdfKind::Sphere, _, Some(radius)) => Sdf::Sphere {
                center,
                radius: radius.val as f32,
            },
            (SdfKind::Box, None, _) => {
                bail!("implicit_function.sdf.side_lengths: required for a box")
            }
            (SdfKind::Sphere, _, None) => {
                bail!("implicit_function.sdf.radius: required for a sphere")
            }
        };
        Ok(SdfVolume {
            sdf,
            alpha: s.alpha.val,
            beta: s.beta.val,
            rainbow: s.feature.rainbow,
            feature: s.feature.val.map(|v| v as f32),
        })
    }

    /// Which SDF parameters the config marks `opt: True`. An error names an `opt: True` on
    /// a parameter the shape does not have (a box's `radius`, a sphere's `side_lengths`).
    pub fn sdf_trainable(&self) -> Result<SdfTrainable> {
        let ImplicitFunctionConfig::SdfVolume(s) = &self.implicit_function else {
            bail!("implicit_function.type: this command needs sdf_volume");
        };
        let p = "implicit_function.sdf";
        match s.sdf.kind {
            SdfKind::Box if s.sdf.radius.as_ref().is_some_and(|r| r.opt) => {
                bail!("{p}.radius.opt: a box has no radius to train (it has side_lengths)")
            }
            SdfKind::Sphere if s.sdf.side_lengths.as_ref().is_some_and(|r| r.opt) => {
                bail!(
                    "{p}.side_lengths.opt: a sphere has no side lengths to train (it has a radius)"
                )
            }
            _ => {}
        }
        Ok(SdfTrainable {
            center: s.sdf.center.opt,
            side_lengths: s.sdf.side_lengths.as_ref().is_some_and(|p| p.opt),
            radius: s.sdf.radius.as_ref().is_some_and(|p| p.opt),
            alpha: s.alpha.opt,
            beta: s.beta.opt,
            feature: s.feature.opt,
        })
    }

    /// The cameras of `data.cameras`, in order, with their names and target image paths:
    /// pytorch3d's `look_at_view_transform(eye, scene_center, up)` with the NDC focal length
    /// and principal point. An error when the config has none.
    pub fn data_cameras(&self) -> Result<Vec<(String, PerspectiveCamera, Option<PathBuf>)>> {
        let cameras = self
            .data
            .cameras
            .as_ref()
            .filter(|c| !c.0.is_empty())
            .context(
                "data.cameras: missing (a `type: train` config lists its training cameras there)",
            )?;
        Ok(cameras
            .0
            .iter()
            .map(|(name, c)| {
                let (r, t) = look_at_view_transform(
                    DVec3::from_array(c.eye),
                    DVec3::from_array(c.scene_center),
                    DVec3::from_array(c.up),
                );
                let camera = PerspectiveCamera {
                    r,
                    t,
                    focal: [c.focal, c.focal],
                    principal_point: c.principal_point,
                };
                (name.clone(), camera, c.image.clone())
            })
            .collect())
    }

    /// The settings of an SDF fit (`type: train`): `training.num_epochs`, `batch_size` and
    /// `lr` (an error names a missing one), the seed, sampler and renderer.
    pub fn sdf_fit_settings(&self) -> Result<SdfFitSettings> {
        let t = self.training()?;
        let job = "fit an SDF volume (type: train)";
        Ok(SdfFitSettings {
            num_epochs: TrainingConfig::required(t.num_epochs, "num_epochs", job)?,
            batch_size: TrainingConfig::required(t.batch_size, "batch_size", job)?,
            lr: TrainingConfig::required(t.lr, "lr", job)?,
            seed: self.seed,
            sampler: self.stratified_sampler()?,
            renderer: self.renderer()?,
        })
    }

    /// The SDF volume as a field for rendering (every parameter constant).
    pub fn sdf_field(&self, device: &Device) -> Result<SdfField> {
        SdfField::fixed(&self.sdf_volume()?, device)
    }

    /// The occupancy grid the renderer uses, with its density threshold (one sample step of
    /// the sampler at `alpha_threshold` opacity), or `None` when the config has no grid.
    pub fn occupancy_grid(&self) -> Option<OccupancyGridParams> {
        let g = self.renderer.occupancy_grid.as_ref()?;
        let n = self.sampler.n_pts_per_ray.max(2) - 1;
        let step = ((self.sampler.max_depth - self.sampler.min_depth) / n as f64).max(1e-6);
        Some(OccupancyGridParams {
            resolution: g.resolution,
            aabb: g.aabb,
            density_threshold: density_threshold(g.alpha_threshold, step),
        })
    }

    /// How training keeps the occupancy grid up to date, when the config has one.
    pub fn grid_schedule(&self) -> Option<GridSchedule> {
        let g = self.renderer.occupancy_grid.as_ref()?;
        Some(GridSchedule {
            grid: self.occupancy_grid()?,
            update_interval: g.update_interval,
            warmup_steps: g.warmup_steps,
            decay: g.decay,
        })
    }

    /// The `training` section, or an error saying it is missing.
    pub fn training(&self) -> Result<&TrainingConfig> {
        self.training
            .as_ref()
            .context("training: section missing from the config")
    }

    /// Everything the NeRF training loop needs from the config; an error names a missing
    /// `training` key.
    pub fn train_settings(&self) -> Result<TrainSettings> {
        let t = self.training()?;
        let model = self.field_spec()?;
        let density_noise = match &self.implicit_function {
            ImplicitFunctionConfig::Nerf(nerf) => nerf.density_noise_std,
            _ => 0.0,
        };
        let job = "train a NeRF";
        let req = |v: Option<usize>, key: &str| TrainingConfig::required(v, key, job);
        Ok(TrainSettings {
            model,
            step: StepSettings {
                batch_size: req(t.batch_size, "batch_size")?,
                rays_from_all_images: t.rays_from_all_images,
                random_background: t.random_background,
                density_noise,
                sampler: self.sampler()?,
                renderer: self.renderer()?,
            },
            seed: self.seed,
            num_epochs: req(t.num_epochs, "num_epochs")?,
            lr: TrainingConfig::required(t.lr, "lr", job)?,
            lr_scheduler_step_size: req(t.lr_scheduler_step_size, "lr_scheduler_step_size")?,
            lr_scheduler_gamma: TrainingConfig::required(
                t.lr_scheduler_gamma,
                "lr_scheduler_gamma",
                job,
            )?,
            checkpoint_interval: req(t.checkpoint_interval, "checkpoint_interval")?,
            render_interval: req(t.render_interval, "render_interval")?,
            resume: t.resume,
            grid: self.grid_schedule(),
            samples_per_step: t.samples_per_step,
            max_rays: self.max_rays_per_step()?,
        })
    }

    /// The most rays an adapted training step may take: those whose drawn samples fit
    /// [`limits::DRAWN_SAMPLES`] when the renderer skips samples (an occupancy grid or early
    /// termination; only evaluated samples hold activations), else [`limits::BATCH_SAMPLES`].
    fn max_rays_per_step(&self) -> Result<usize> {
        use crate::app::config::limits;
        let skips = self.grid_schedule().is_some() || self.renderer()?.early_termination > 0.0;
        let budget = if skips {
            limits::DRAWN_SAMPLES
        } else {
            limits::BATCH_SAMPLES
        };
        Ok(budget / self.sampler.n_pts_per_ray.max(1))
    }

    /// The checkpoint training reads and writes for `training.checkpoint_path`, by the one
    /// rule of [`crate::io::checkpoint_file::resolve_for`] (a directory holding several
    /// checkpoints is an error; one holding none, or a new path, starts a fresh run), and its
    /// `.log.jsonl` beside it; previews go to `images`.
    pub fn train_paths(&self, images: &Path) -> Result<TrainPaths> {
        use crate::io::checkpoint_file::{resolve_for, Purpose};
        let training = self.training()?;
        // Training never falls back to the shipped model: it needs a place of its own.
        let configured =
            TrainingConfig::required(training.checkpoint(), "checkpoint_path", "train a NeRF")?;
        let checkpoint = resolve_for(configured, &self.dataset_stem(), Purpose::Train)
            .context("training.checkpoint_path")?;
        Ok(TrainPaths {
            log: checkpoint.with_extension("log.jsonl"),
            checkpoint,
            images: images.to_path_buf(),
        })
    }

    /// The checkpoint a command reads — the one path for render, eval, bench, report, view and
    /// export: `given` (the `--checkpoint` option), else the config's
    /// `training.checkpoint_path`, else the shipped [`SHIPPED_CHECKPOINT`]; a directory is
    /// resolved to the checkpoint it holds by
    /// [`crate::io::checkpoint_file::resolve`] where it can be (where it cannot, the directory
    /// itself, whose [`Config::ensure_checkpoint`] error says why).
    pub fn checkpoint(&self, given: Option<&Path>) -> PathBuf {
        let configured = self.training.as_ref().and_then(|t| t.checkpoint());
        let path = given
            .or(configured)
            .unwrap_or(Path::new(SHIPPED_CHECKPOINT));
        crate::io::checkpoint_file::resolve(path, &self.dataset_stem())
            .unwrap_or_else(|_| path.to_path_buf())
    }

    /// An error when `path` (from [`Config::checkpoint`]) is not a checkpoint file: for the
    /// config's own `training.checkpoint_path`, it names that key and what may be put there;
    /// for a directory, the one rule's error (none, or several, naming them).
    pub fn ensure_checkpoint(&self, path: &Path) -> Result<()> {
        use crate::io::checkpoint_file::{relative_note, resolve};
        if path.is_file() {
            return Ok(());
        }
        let configured = self.training.as_ref().and_then(|t| t.checkpoint());
        if let Some(c) = configured.filter(|c| !c.exists()) {
            if path == self.checkpoint(None) {
                bail!(
                    "checkpoint {} not found (training.checkpoint_path; put a checkpoint there, ours or the homework's torch.save file, or pass --checkpoint{}){}",
                    c.display(),
                    self.shipped_model_hint(),
                    relative_note(c)
                );
            }
        }
        if path.is_dir() {
            resolve(path, &self.dataset_stem())?;
        }
        crate::io::checkpoint_file::ensure_checkpoint_file(path)
    }

    /// Where a user without this config's checkpoint finds a shipped model that renders well:
    /// the hash-grid model for an `ngp` field; for the MLP, the shipped checkpoint when this
    /// config renders with an occupancy grid (as it was trained), else the densely trained
    /// [`HOMEWORK_CHECKPOINT`] or the `lego` config, since the shipped MLP rendered densely
    /// shows the ghost density its grid removes.
    fn shipped_model_hint(&self) -> String {
        match &self.implicit_function {
            ImplicitFunctionConfig::Ngp(_) => format!(
                "; the shipped hash-grid model is {SHIPPED_NGP_CHECKPOINT}, rendered by `nerf render --config lego_ngp` from the repository root"
            ),
            _ if self.occupancy_grid().is_some() => {
                format!(", e.g. the shipped {SHIPPED_CHECKPOINT}")
            }
            _ => format!(
                "; from the repository root, `nerf render --config lego` renders the shipped {SHIPPED_CHECKPOINT} best, with the occupancy grid it was trained with (this config, dense, would show ghost density), and --checkpoint {HOMEWORK_CHECKPOINT} is a model trained densely, as this config renders"
            ),
        }
    }

    /// `nerf_<data.dataset_name>` (`nerf_scene` without one): the file name, less its
    /// extension, of the checkpoint in a `training.checkpoint_path` directory.
    pub fn dataset_stem(&self) -> String {
        format!(
            "nerf_{}",
            self.data.dataset_name.as_deref().unwrap_or("scene")
        )
    }

    /// A trained field for rendering or evaluating with this config, whatever its kind:
    /// weights from the checkpoint at `path` and the occupancy grid the config asks for.
    pub fn load_field(
        &self,
        path: &Path,
        device: &Device,
    ) -> Result<Box<dyn crate::render::field::Field + Send + Sync>> {
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
        crate::core::term::note(&format!(
            "loaded {} (epoch {}, {} Adam {})",
            path.display(),
            info.epoch,
            info.adam_step,
            plural(info.adam_step as usize, "step", "steps")
        ));
        if state
            .occupancy
            .as_ref()
            .is_some_and(|g| g.occupied_fraction() == 0.0)
        {
            crate::core::term::note(
                "warning: the occupancy grid has no occupied cell: the model has no density above \
                 the grid's threshold anywhere, so every render is empty",
            );
        }
        Ok((state, info))
    }
}
