//! Range checks of a typed config: every value within its limits ([`super::limits`]) and the
//! sections consistent with each other, the first bad value an error naming its key.

use anyhow::{bail, Result};

use super::limits;
use super::renderer::OccupancyGridConfig;
use super::Config;
use nerf_core::key_checks::{count_in_range, finite};
use nerf_field::registry::kind_names;

impl Config {
    /// Checks every value's range, naming the key of the first bad one.
    pub fn validate(&self) -> Result<()> {
        let [w, h] = self.data.image_size.unwrap_or([1, 1]);
        if w == 0 || h == 0 || w > limits::IMAGE_SIDE || h > limits::IMAGE_SIDE {
            bail!(
                "data.image_size: width and height must be 1 to {} (got [{w}, {h}])",
                limits::IMAGE_SIDE
            );
        }
        if self.data.pixel_budget == Some(0) {
            bail!("data.pixel_budget: must be at least 1 pixel");
        }
        if let Some(d) = self.data.downscale {
            if !(d.is_finite() && (1.0..=64.0).contains(&d)) {
                bail!("data.downscale: must be a number from 1 to 64 (got {d})");
            }
        }
        count_in_range(
            "sampler.n_pts_per_ray",
            self.sampler.n_pts_per_ray,
            limits::PTS_PER_RAY,
        )?;
        for (key, n) in [
            (
                "sampler.n_pts_per_ray_fine",
                self.sampler.n_pts_per_ray_fine,
            ),
            ("sampler.n_pts_far", self.sampler.n_pts_far),
        ] {
            if n > limits::PTS_PER_RAY {
                bail!("{key}: must be at most {} (got {n})", limits::PTS_PER_RAY);
            }
        }
        self.validate_renderer()?;
        self.validate_sampler()?;
        self.validate_cameras()?;
        self.implicit_function.field().validate()?;
        self.validate_data_cameras()?;
        self.validate_training()
    }

    /// The `renderer` section, and that its accelerations have a NeRF to work on.
    fn validate_renderer(&self) -> Result<()> {
        if self.renderer.chunk_size == 0 {
            bail!("renderer.chunk_size: must be at least 1");
        }
        let early = self.renderer.early_termination;
        finite("renderer.early_termination", early)?;
        if !(0.0..1.0).contains(&early) {
            bail!("renderer.early_termination: must be in [0, 1) (got {early})");
        }
        if let Some(g) = &self.renderer.occupancy_grid {
            validate_occupancy_grid(g)?;
        }
        let accelerated = early > 0.0 || self.renderer.occupancy_grid.is_some();
        if accelerated && self.implicit_function.is_sdf_volume() {
            bail!(
                "renderer.occupancy_grid and renderer.early_termination need implicit_function.type {}",
                kind_names(true)
            );
        }
        if accelerated && self.sampler.n_pts_per_ray_fine > 0 {
            bail!("sampler.n_pts_per_ray_fine (coarse-to-fine sampling) renders densely: set renderer.occupancy_grid=null and renderer.early_termination=0");
        }
        Ok(())
    }

    /// The `sampler` depth range.
    fn validate_sampler(&self) -> Result<()> {
        finite("sampler.min_depth", self.sampler.min_depth)?;
        finite("sampler.max_depth", self.sampler.max_depth)?;
        if self.sampler.min_depth < 0.0 {
            bail!(
                "sampler.min_depth: must be non-negative (got {})",
                self.sampler.min_depth
            );
        }
        if self.sampler.min_depth > self.sampler.max_depth {
            bail!(
                "sampler.min_depth: must not exceed sampler.max_depth ({} > {})",
                self.sampler.min_depth,
                self.sampler.max_depth
            );
        }
        // The sampler itself checks the rest (n_pts_far, far_depth, their type).
        self.sampler.sampler()?;
        Ok(())
    }

    /// The `cameras` section, and the pixel count of all its frames.
    fn validate_cameras(&self) -> Result<()> {
        let (w, h) = self.image_size();
        let c = &self.cameras;
        finite("cameras.radius", c.radius)?;
        finite("cameras.focal_length", c.focal_length)?;
        for (i, v) in c.up.iter().enumerate() {
            finite(&format!("cameras.up[{i}]"), *v)?;
        }
        if c.radius <= 0.0 {
            bail!("cameras.radius: must be positive (got {})", c.radius);
        }
        if c.focal_length <= 0.0 {
            bail!(
                "cameras.focal_length: must be positive (got {})",
                c.focal_length
            );
        }
        count_in_range("cameras.n_poses", c.n_poses, limits::POSES)?;
        if c.n_poses * w * h > limits::FRAME_PIXELS {
            bail!(
                "cameras.n_poses: {} frames of {w}x{h} exceed {} pixels in all (fewer poses or a smaller data.image_size)",
                c.n_poses,
                limits::FRAME_PIXELS
            );
        }
        if c.up.iter().all(|v| *v == 0.0) {
            bail!("cameras.up: must be a non-zero vector");
        }
        Ok(())
    }

    /// The `training` section, when present.
    fn validate_training(&self) -> Result<()> {
        let Some(t) = &self.training else {
            return Ok(());
        };
        for (key, v) in [
            ("training.lr", t.lr),
            ("training.lr_scheduler_gamma", t.lr_scheduler_gamma),
        ] {
            if let Some(v) = v {
                finite(key, v)?;
                if v <= 0.0 {
                    bail!("{key}: must be positive (got {v})");
                }
            }
        }
        if let Some(batch) = t.batch_size {
            let per_ray = self.sampler.drawn_per_ray() + self.sampler.n_pts_per_ray_fine;
            let samples = batch.saturating_mul(per_ray);
            if samples > limits::BATCH_SAMPLES {
                bail!(
                    "training.batch_size: {batch} rays x {} points is {samples} samples per step, more than {}",
                    per_ray,
                    limits::BATCH_SAMPLES
                );
            }
        }
        for (key, v) in [
            ("training.num_epochs", t.num_epochs),
            ("training.batch_size", t.batch_size),
            ("training.lr_scheduler_step_size", t.lr_scheduler_step_size),
            ("training.checkpoint_interval", t.checkpoint_interval),
            ("training.render_interval", t.render_interval),
        ] {
            if v == Some(0) {
                bail!("{key}: must be at least 1");
            }
        }
        let weight = t.distortion_loss;
        finite("training.distortion_loss", weight)?;
        if weight < 0.0 {
            bail!("training.distortion_loss: must be non-negative (got {weight})");
        }
        if weight > 0.0 && self.sampler.n_pts_per_ray_fine > 0 {
            bail!("training.distortion_loss needs a sampler of type stratified or depth_then_disparity, not coarse-to-fine (sampler.n_pts_per_ray_fine)");
        }
        Ok(())
    }

    /// `data.cameras`: finite values, a positive focal length, a non-zero up vector and an eye
    /// away from the scene centre (else pytorch3d's look-at divides by zero).
    fn validate_data_cameras(&self) -> Result<()> {
        let Some(cameras) = &self.data.cameras else {
            return Ok(());
        };
        if cameras.0.len() > limits::POSES {
            bail!("data.cameras: at most {} cameras", limits::POSES);
        }
        for (name, c) in &cameras.0 {
            let key = format!("data.cameras.{name}");
            let values = c
                .eye
                .iter()
                .chain(&c.scene_center)
                .chain(&c.up)
                .chain(&c.principal_point)
                .chain([&c.focal]);
            for v in values {
                finite(&key, *v)?;
            }
            if c.focal <= 0.0 {
                bail!("{key}.focal: must be positive (got {})", c.focal);
            }
            if c.up.iter().all(|v| *v == 0.0) {
                bail!("{key}.up: must be a non-zero vector");
            }
            let d: f64 = (0..3).map(|k| (c.eye[k] - c.scene_center[k]).powi(2)).sum();
            if d.sqrt() < 1e-5 {
                bail!(
                    "{key}.eye: equals scene_center {:?}, so the camera has no viewing direction",
                    c.scene_center
                );
            }
        }
        Ok(())
    }
}

fn validate_occupancy_grid(g: &OccupancyGridConfig) -> Result<()> {
    let key = "renderer.occupancy_grid";
    if g.resolution == 0 || g.resolution > 512 {
        bail!("{key}.resolution: must be 1 to 512 (got {})", g.resolution);
    }
    for (i, v) in g.aabb.iter().enumerate() {
        finite(&format!("{key}.aabb[{i}]"), *v)?;
    }
    for k in 0..3 {
        if g.aabb[k] >= g.aabb[k + 3] {
            bail!(
                "{key}.aabb: min must be below max on every axis (axis {k}: {} >= {})",
                g.aabb[k],
                g.aabb[k + 3]
            );
        }
    }
    finite(&format!("{key}.alpha_threshold"), g.alpha_threshold)?;
    if !(g.alpha_threshold > 0.0 && g.alpha_threshold < 1.0) {
        bail!(
            "{key}.alpha_threshold: must be in (0, 1) (got {})",
            g.alpha_threshold
        );
    }
    for (name, decay) in [
        ("decay", Some(g.decay)),
        ("decay_without_backdrop", g.decay_without_backdrop),
    ] {
        let Some(decay) = decay else { continue };
        finite(&format!("{key}.{name}"), decay)?;
        if !(decay > 0.0 && decay <= 1.0) {
            bail!("{key}.{name}: must be in (0, 1] (got {decay})");
        }
    }
    if g.update_interval == 0 {
        bail!("{key}.update_interval: must be at least 1");
    }
    finite(&format!("{key}.camera_clearance"), g.camera_clearance)?;
    if !(0.0..1.0).contains(&g.camera_clearance) {
        bail!(
            "{key}.camera_clearance: must be in [0, 1) (got {})",
            g.camera_clearance
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::test_box_with as box_with;

    fn err(overrides: &[&str]) -> String {
        format!("{:#}", box_with(overrides).unwrap_err())
    }

    #[test]
    fn errors_name_the_key() {
        for (setting, key) in [
            ("sampler.n_pts_per_rays=3", "n_pts_per_rays"),
            ("sampler.n_pts_per_ray=abc", "sampler.n_pts_per_ray"),
            ("sampler.n_pts_per_ray=0", "sampler.n_pts_per_ray"),
            ("sampler.min_depth=-1", "sampler.min_depth"),
            ("sampler.min_depth=6", "sampler.min_depth"),
            ("data.image_size=[0,5]", "data.image_size"),
            ("renderer.chunk_size=0", "renderer.chunk_size"),
            (
                "implicit_function.beta.val=.nan",
                "implicit_function.beta.val",
            ),
            ("implicit_function.sdf.center.val=[0, .inf, 0]", "center"),
            ("implicit_function.sdf.colour=1", "implicit_function.sdf"),
            ("implicit_function.type=mesh", "implicit_function.type"),
            ("cameras.radius=.nan", "cameras"),
            (
                "renderer.occupancy_grid.decay=0",
                "renderer.occupancy_grid.decay",
            ),
            (
                "renderer.occupancy_grid.decay_without_backdrop=1.5",
                "renderer.occupancy_grid.decay_without_backdrop: must be in (0, 1]",
            ),
            ("nokey", "key.sub=value"),
        ] {
            let e = err(&[setting]);
            assert!(e.contains(key), "{setting}: {e}");
        }
    }
}
