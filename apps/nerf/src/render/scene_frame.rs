//! The frame a checkpoint's model lives in, at the commands' edge: a model trained on a
//! capture stores the capture's normalisation ([`nerf::io::checkpoint::SCENE_TRANSFORM_KEY`]),
//! and `eval`, `export` and a resumed `train` read the capture's cameras in that frame
//! rather than in the one recomputed from the cameras they were given (which moves when the
//! cameras differ: a subset, a re-run of structure from motion that kept the same gauge).
//! `render` and `view` show such a model from the path stored beside the transform, a spiral
//! in front of a forward-facing capture or else an orbit ([`render_cameras`]).

use std::path::Path;

use anyhow::Result;
use glam::DVec3;

use nerf::config::{BackgroundConfig, Config};
use nerf::core::camera::PerspectiveCamera;
use nerf::io::checkpoint::{self, read_metadata};
use nerf::io::checkpoint_file::{detect_format, CheckpointFormat};
use nerf::io::dataset::{CaptureOrbit, CaptureSpiral, Normalisation, SceneTransform};

/// The scene normalisation stored in the checkpoint at `path`; `None` when it stores none
/// (a NeRF-synthetic model, an older checkpoint, a PyTorch file) or is not a file (loading
/// the model then says what is wrong with it). An error for a stored transform that does not
/// read.
pub fn stored_transform(path: &Path) -> Result<Option<SceneTransform>> {
    if !path.is_file() || detect_format(path).ok() != Some(CheckpointFormat::Safetensors) {
        return Ok(None);
    }
    Ok(checkpoint::SCENE_TRANSFORM.read(&read_metadata(path)?, path)?)
}

/// The depth range and the cube of an object fit ([`adopt_object_fit`]).
pub type ObjectFitStored = (Option<(f64, f64)>, Option<[f64; 6]>);

/// What training stored in `checkpoint` of the object it fitted the model to, put into
/// `config`: the depth range it narrowed the sampler to (the model is empty only where it
/// was sampled, so it is shown over the same depths), and the cube it fitted the field and
/// the occupancy grid to (`Config::fit_to_object`). Returns both (each `None` when not
/// stored), or `None` for a file that is not one of our checkpoints.
pub fn adopt_object_fit(config: &mut Config, checkpoint: &Path) -> Result<Option<ObjectFitStored>> {
    if !checkpoint.is_file()
        || detect_format(checkpoint).ok() != Some(CheckpointFormat::Safetensors)
    {
        return Ok(None);
    }
    let meta = read_metadata(checkpoint)?;
    let depths = checkpoint::SAMPLE_DEPTHS.read(&meta, checkpoint)?;
    if let Some((near, far)) = depths {
        (config.sampler.min_depth, config.sampler.max_depth) = (near, far);
    }
    let cube = checkpoint::OBJECT_BOX.read(&meta, checkpoint)?;
    if let Some(cube) = cube {
        config.fit_to_object(cube);
    }
    Ok(Some((depths, cube)))
}

/// What a command that shows or scores the model at `checkpoint` takes from it into
/// `config`: with `renderer.background: auto`, the background training stored; the depth
/// range and the cube training fitted the model to, when it did (an object photographed
/// alone, [`adopt_object_fit`]); with
/// `image_size_too` and no `data.image_size`, the training images' size (renders of other
/// views: `render`, `view`). Nothing for a file that is not one of our checkpoints (loading
/// the model then says what is wrong with it).
pub fn adopt_stored_settings(
    config: &mut Config,
    checkpoint: &Path,
    image_size_too: bool,
) -> Result<()> {
    if !checkpoint.is_file()
        || detect_format(checkpoint).ok() != Some(CheckpointFormat::Safetensors)
    {
        return Ok(());
    }
    let meta = read_metadata(checkpoint)?;
    if config.renderer.background_is_auto() {
        if let Some(c) = checkpoint::BACKGROUND.read(&meta, checkpoint)? {
            config.renderer.background = Some(BackgroundConfig::Colour(c));
        }
    }
    adopt_object_fit(config, checkpoint)?;
    if image_size_too && config.data.image_size.is_none() {
        if let Some((w, h)) = checkpoint::IMAGE_SIZE.read(&meta, checkpoint)? {
            config.data.image_size = Some([w, h]);
        }
    }
    Ok(())
}

/// The path a capture's model is shown along: a spiral in front of a forward-facing capture,
/// an orbit around any other.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CapturePath {
    /// Around the z axis, looking at the origin.
    Orbit(CaptureOrbit),
    /// In front of the cameras, looking at a focus point ahead of them.
    Spiral(CaptureSpiral),
}

impl CapturePath {
    /// `n_poses` views along the path.
    pub fn cameras(&self, n_poses: usize) -> Vec<PerspectiveCamera> {
        match self {
            CapturePath::Orbit(o) => o.cameras(n_poses),
            CapturePath::Spiral(s) => s.cameras(n_poses),
        }
    }

    /// The point every view looks at.
    pub fn target(&self) -> DVec3 {
        match self {
            CapturePath::Orbit(_) => DVec3::ZERO,
            CapturePath::Spiral(s) => s.focus(),
        }
    }

    /// The views' up direction.
    pub fn up(&self) -> DVec3 {
        match self {
            CapturePath::Orbit(_) => DVec3::Z,
            CapturePath::Spiral(s) => s.up,
        }
    }

    /// What `n_poses` views along the path are, for stderr.
    fn describe(&self, n_poses: usize) -> String {
        match self {
            CapturePath::Orbit(o) => format!(
                "{n_poses} views on the capture's orbit: radius {:.3}, height {:.3} around the \
                 z axis, looking at the origin, NDC focal ({:.3}, {:.3})",
                o.radius, o.height, o.focal[0], o.focal[1]
            ),
            CapturePath::Spiral(s) => {
                let (c, f) = (s.centre, s.focus());
                format!(
                    "{n_poses} views on a spiral in front of the capture's cameras \
                     (forward-facing): centre ({:.3}, {:.3}, {:.3}), radii {:.3} across, \
                     {:.3} up, {:.3} along the view, looking at ({:.3}, {:.3}, {:.3}) {:.3} \
                     ahead, NDC focal ({:.3}, {:.3})",
                    c.x,
                    c.y,
                    c.z,
                    s.radii[0],
                    s.radii[1],
                    s.radii[2],
                    f.x,
                    f.y,
                    f.z,
                    s.focus_distance,
                    s.focal[0],
                    s.focal[1]
                )
            }
        }
    }
}

/// The views `nerf render` renders and `nerf view` starts from.
#[derive(Debug, Clone, PartialEq)]
pub struct DefaultViews {
    /// The cameras.
    pub cameras: Vec<PerspectiveCamera>,
    /// The capture path they lie on, for a model trained on a capture (`None`: the config's
    /// surround cameras).
    pub path: Option<CapturePath>,
}

impl DefaultViews {
    /// The config's surround cameras (the homework's views).
    pub fn surround(config: &Config) -> Self {
        Self {
            cameras: config.surround_cameras(),
            path: None,
        }
    }
}

/// The views `nerf render` and `nerf view` show the model at `checkpoint` from:
/// `cameras.n_poses` views on the capture's path when the checkpoint was trained on a capture
/// (the stored [`CaptureSpiral`] of a forward-facing capture, else the stored
/// [`CaptureOrbit`], or [`CaptureOrbit::normalised_default`] for a capture checkpoint that
/// stores neither), else the config's surround cameras (the homework's). Says on stderr which,
/// for a capture.
pub fn render_cameras(config: &Config, checkpoint: &Path) -> Result<DefaultViews> {
    let n_poses = config.cameras.n_poses;
    if !checkpoint.is_file()
        || detect_format(checkpoint).ok() != Some(CheckpointFormat::Safetensors)
    {
        return Ok(DefaultViews::surround(config));
    }
    let meta = read_metadata(checkpoint)?;
    let spiral = checkpoint::CAPTURE_SPIRAL.read(&meta, checkpoint)?;
    let orbit = checkpoint::CAPTURE_ORBIT.read(&meta, checkpoint)?;
    let path = match (spiral, orbit) {
        (Some(spiral), _) => CapturePath::Spiral(spiral),
        (None, Some(orbit)) => CapturePath::Orbit(orbit),
        (None, None)
            if checkpoint::SCENE_TRANSFORM
                .read(&meta, checkpoint)?
                .is_some() =>
        {
            nerf::core::term::note(&format!(
                "note: {} was trained on a capture but stores no orbit (written before orbits \
                 were stored): using a default one in the normalised frame",
                checkpoint.display()
            ));
            CapturePath::Orbit(CaptureOrbit::normalised_default())
        }
        (None, None) => return Ok(DefaultViews::surround(config)),
    };
    nerf::core::term::note(&path.describe(n_poses));
    Ok(DefaultViews {
        cameras: path.cameras(n_poses),
        path: Some(path),
    })
}

/// Says on stderr how the frame of the data in `data_dir` relates to the checkpoint's: when
/// the stored transform was applied and differs from the one the cameras give, both; when the
/// checkpoint stores none for a capture, that the recomputed one is used; when it stores one
/// for a NeRF-synthetic scene, that it does not apply.
pub fn note_scene_frame(
    data_dir: &Path,
    checkpoint: &Path,
    stored: Option<SceneTransform>,
    normalisation: Option<&Normalisation>,
) {
    let show = |t: &SceneTransform| {
        let c = t.center;
        format!(
            "centre ({:.4}, {:.4}, {:.4}), scale {:.5}",
            c.x, c.y, c.z, t.scale
        )
    };
    let note = match (stored, normalisation) {
        (Some(_), Some(n)) if !n.is_from_cameras() => format!(
            "note: {}: using the scene normalisation stored in {} ({}), not the one these \
             cameras give ({})",
            data_dir.display(),
            checkpoint.display(),
            show(&n.applied),
            n.from_cameras
                .as_ref()
                .map_or_else(|| "none: too few cameras".to_string(), show)
        ),
        (None, Some(_)) => format!(
            "note: {} stores no scene normalisation (trained before it was stored, or not on a \
             capture): the capture {} is normalised from its own cameras",
            checkpoint.display(),
            data_dir.display()
        ),
        (Some(_), None) => format!(
            "note: {} was trained on a capture, and stores its normalisation; {} is a \
             NeRF-synthetic scene, used in its own frame",
            checkpoint.display(),
            data_dir.display()
        ),
        _ => return,
    };
    nerf::core::term::note(&note);
}
