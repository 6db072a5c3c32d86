//! The `data` section: image size, dataset name and directory, and the training cameras of
//! an SDF fit, with what they become at run time.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use glam::DVec3;
use serde::Deserialize;

use super::Config;
use crate::core::camera::{look_at_view_transform, PerspectiveCamera};
use crate::core::frame_camera::FrameCamera;

/// The `data` section.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    /// `[width, height]` in pixels.
    pub image_size: [usize; 2],
    /// `data.dataset_name`, e.g. `lego`: names the default data directory and the checkpoint file.
    pub dataset_name: Option<String>,
    /// Directory holding the dataset (extension; default `../shared/data/<dataset_name>`).
    pub data_dir: Option<PathBuf>,
    /// `data.cameras`: the training cameras of an SDF fit (`type: train`), in order.
    pub cameras: Option<DataCameras>,
    /// Extension, `data.downscale`: load a dataset's images at their own size divided by this
    /// (rounded, at least 1 pixel), intrinsics following, instead of at `image_size`.
    pub downscale: Option<f64>,
}

impl DataConfig {
    /// Image width and height (`data.image_size`).
    pub fn image_size(&self) -> (usize, usize) {
        (self.image_size[0], self.image_size[1])
    }

    /// `nerf_<data.dataset_name>` (`nerf_scene` without one): the file name, less its
    /// extension, of the checkpoint in a `training.checkpoint_path` directory.
    pub fn dataset_stem(&self) -> String {
        format!("nerf_{}", self.dataset_name.as_deref().unwrap_or("scene"))
    }

    /// The size a dataset in `data_dir` is loaded at: `image_size`, or with `downscale` its
    /// first training frame's own size (a capture camera's pixel size, or a NeRF-synthetic
    /// image file's) divided by the factor, rounded, at least 1.
    pub fn dataset_image_size(&self, data_dir: &Path) -> Result<(usize, usize)> {
        let Some(factor) = self.downscale else {
            return Ok(self.image_size());
        };
        let frames = crate::io::dataset::read_split(data_dir, crate::io::dataset::Split::Train)?;
        let first = frames
            .first()
            .with_context(|| format!("{}: no training frames", data_dir.display()))?;
        let (w, h) = match &first.camera {
            FrameCamera::Colmap(c) => c.size,
            FrameCamera::Pinhole(_) => {
                let (w, h) = image::image_dimensions(&first.file_path).with_context(|| {
                    format!("data.downscale: size of {}", first.file_path.display())
                })?;
                (w as usize, h as usize)
            }
        };
        let scaled = |v: usize| ((v as f64 / factor).round() as usize).max(1);
        let (w, h) = (scaled(w), scaled(h));
        let most = super::limits::IMAGE_SIDE;
        if w > most || h > most {
            anyhow::bail!(
                "data.downscale={factor}: {} is {w}x{h} at that scale, more than {most} pixels \
                 on a side; use a larger factor",
                first.file_path.display()
            );
        }
        Ok((w, h))
    }
}

/// One camera of `data.cameras` (the homework's `train_box.yaml`): pytorch3d's
/// `look_at_view_transform(eye, scene_center, up)` with an NDC focal length and principal
/// point, and the image it sees.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DataCameraConfig {
    /// NDC focal length (both axes).
    pub focal: f64,
    /// Camera position in world units.
    pub eye: [f64; 3],
    /// NDC principal point `(p_x, p_y)`.
    pub principal_point: [f64; 2],
    /// The point the camera looks at.
    pub scene_center: [f64; 3],
    /// Up direction.
    pub up: [f64; 3],
    /// The target image: a `.npy` float array `(H, W, 3)`, relative to the working directory
    /// (needed to train).
    pub image: Option<PathBuf>,
}

impl DataCameraConfig {
    /// The camera: pytorch3d's `look_at_view_transform(eye, scene_center, up)` with the NDC
    /// focal length and principal point.
    pub fn camera(&self) -> PerspectiveCamera {
        let (r, t) = look_at_view_transform(
            DVec3::from_array(self.eye),
            DVec3::from_array(self.scene_center),
            DVec3::from_array(self.up),
        );
        PerspectiveCamera {
            r,
            t,
            focal: [self.focal, self.focal],
            principal_point: self.principal_point,
        }
    }
}

/// `data.cameras`: named cameras in the order written.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DataCameras(pub Vec<(String, DataCameraConfig)>);

impl<'de> Deserialize<'de> for DataCameras {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct Ordered;
        impl<'de> serde::de::Visitor<'de> for Ordered {
            type Value = DataCameras;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a mapping of camera names to cameras")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> std::result::Result<DataCameras, A::Error> {
                let mut cameras = Vec::new();
                while let Some((name, camera)) = map.next_entry::<String, DataCameraConfig>()? {
                    cameras.push((name, camera));
                }
                Ok(DataCameras(cameras))
            }
        }
        d.deserialize_map(Ordered)
    }
}

impl Config {
    /// Image width and height (`data.image_size`).
    pub fn image_size(&self) -> (usize, usize) {
        self.data.image_size()
    }

    /// The cameras of `data.cameras`, in order, with their names and target image paths (see
    /// [`DataCameraConfig::camera`]). An error when the config has none.
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
            .map(|(name, c)| (name.clone(), c.camera(), c.image.clone()))
            .collect())
    }

    /// [`DataConfig::dataset_stem`].
    pub fn dataset_stem(&self) -> String {
        self.data.dataset_stem()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn downscale_gives_the_photos_size_over_n_within_the_limit() {
        let (dir, json) = crate::io::test_files::temp_file("transforms.json");
        let frame = |z: f64| {
            format!(
                r#"{{"file_path": "a.jpg", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,{z}],[0,0,0,1]]}}"#
            )
        };
        std::fs::write(
            &json,
            format!(
                r#"{{"fl_x": 9e4, "cx": 5e4, "cy": 3e4, "w": 100000, "h": 60000, "frames": [{}, {}]}}"#,
                frame(4.0),
                frame(5.0)
            ),
        )
        .unwrap();
        let mut data = DataConfig {
            image_size: [8, 8],
            dataset_name: None,
            data_dir: None,
            cameras: None,
            downscale: None,
        };
        assert_eq!(data.dataset_image_size(dir.path()).unwrap(), (8, 8));
        data.downscale = Some(50.0);
        assert_eq!(data.dataset_image_size(dir.path()).unwrap(), (2000, 1200));
        data.downscale = Some(2.0);
        let err = data.dataset_image_size(dir.path()).unwrap_err().to_string();
        assert!(err.contains("50000x30000") && err.contains("4096"), "{err}");
    }
}
