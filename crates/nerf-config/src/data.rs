//! The `data` section: image size, dataset name and directory, and the training cameras of
//! an SDF fit, with what they become at run time.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use glam::DVec3;
use serde::Deserialize;

use super::Config;
use nerf_core::camera::Camera;
use nerf_core::camera::{look_at_view_transform, PerspectiveCamera};

/// The `data` section.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    /// `[width, height]` in pixels. Optional: a config without it (the capture configs) loads
    /// a dataset at its photos' own aspect ([`DataConfig::dataset_image_size`]) and renders
    /// other views at `DEFAULT_VIEW_SIZE` or the size a checkpoint was trained at.
    #[serde(default)]
    pub image_size: Option<[usize; 2]>,
    /// `data.dataset_name`, e.g. `lego`: names the default data directory and the checkpoint file.
    pub dataset_name: Option<String>,
    /// Directory holding the dataset (extension; default `../shared/data/<dataset_name>`).
    pub data_dir: Option<PathBuf>,
    /// `data.cameras`: the training cameras of an SDF fit (`type: train`), in order.
    pub cameras: Option<DataCameras>,
    /// Extension, `data.downscale`: load a dataset's images at their own size divided by this
    /// (rounded, at least 1 pixel), intrinsics following, instead of at `image_size`.
    pub downscale: Option<f64>,
    /// Extension, `data.pixel_budget`: without `image_size` or `downscale`, training loads
    /// photos of more pixels than this at their size divided by the smallest whole factor that
    /// brings them within it ([`photo_scale_factor`]); default [`DEFAULT_PIXEL_BUDGET`].
    pub pixel_budget: Option<usize>,
}

/// Pixels a training photo keeps at most by default (640×480): 300 photos of it are 92 M
/// pixels, about 30 epochs' rays of a 10-minute hash-grid run at 16k rays per step, and a
/// photo's render at eval stays short (measured: docs/own-scene.md#pixel-budget).
pub const DEFAULT_PIXEL_BUDGET: usize = 640 * 480;

/// The size renders of a config without `data.image_size` take when nothing else gives one
/// (no checkpoint stores its training size).
pub(crate) const DEFAULT_VIEW_SIZE: (usize, usize) = (256, 256);

/// The smallest whole factor `n ≥ 1` with `(w / n) · (h / n) ≤ budget`: integer factors keep
/// each training pixel a whole block of photo pixels.
pub fn photo_scale_factor((w, h): (usize, usize), budget: usize) -> usize {
    let pixels = (w as f64) * (h as f64);
    let mut n = (pixels / budget.max(1) as f64).sqrt().ceil().max(1.0) as usize;
    // The square root's rounding may leave one too few or too many.
    while n > 1 && (w as f64 / (n - 1) as f64) * (h as f64 / (n - 1) as f64) <= budget as f64 {
        n -= 1;
    }
    while (w as f64 / n as f64) * (h as f64 / n as f64) > budget as f64 {
        n += 1;
    }
    n
}

/// What a dataset is loaded for: training (within the pixel budget) or scoring (the photos'
/// own size).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SizeUse {
    /// `nerf train`: photos over the pixel budget are scaled down.
    Training,
    /// `nerf eval` and exports: the photos' own size.
    Scoring,
}

impl DataConfig {
    /// Image width and height (`data.image_size`, else [`DEFAULT_VIEW_SIZE`]).
    pub(crate) fn image_size(&self) -> (usize, usize) {
        self.image_size.map_or(DEFAULT_VIEW_SIZE, |[w, h]| (w, h))
    }

    /// `nerf_<data.dataset_name>` (`nerf_scene` without one): the file name, less its
    /// extension, of the checkpoint in a `training.checkpoint_path` directory.
    pub(crate) fn dataset_stem(&self) -> String {
        format!("nerf_{}", self.dataset_name.as_deref().unwrap_or("scene"))
    }

    /// The size a dataset in `data_dir` is loaded at for `usage`: with `downscale`, its
    /// first training frame's own size (a capture camera's pixel size, or an image file's)
    /// divided by the factor, rounded, at least 1; else `image_size` when the config gives
    /// one; else the photos' own size, for training divided by [`photo_scale_factor`] of the
    /// pixel budget.
    pub fn dataset_image_size(&self, data_dir: &Path, usage: SizeUse) -> Result<(usize, usize)> {
        let factor = match (self.downscale, self.image_size, usage) {
            (Some(factor), _, _) => factor,
            (None, Some([w, h]), _) => return Ok((w, h)),
            (None, None, SizeUse::Scoring) => 1.0,
            (None, None, SizeUse::Training) => {
                let budget = self.pixel_budget.unwrap_or(DEFAULT_PIXEL_BUDGET);
                photo_scale_factor(photo_size(data_dir)?, budget) as f64
            }
        };
        let (w, h) = photo_size(data_dir)?;
        let scaled = |v: usize| ((v as f64 / factor).round() as usize).max(1);
        let (w, h) = (scaled(w), scaled(h));
        let most = super::limits::IMAGE_SIDE;
        if w > most || h > most {
            anyhow::bail!(
                "{}: the photos are {w}x{h} at 1/{factor} scale, more than {most} pixels on a \
                 side; set data.downscale to a larger factor",
                data_dir.display()
            );
        }
        Ok((w, h))
    }
}

/// The pixel size of the first training frame of the dataset in `data_dir`: a capture
/// camera's, or a NeRF-synthetic image file's.
pub(crate) fn photo_size(data_dir: &Path) -> Result<(usize, usize)> {
    let frames = nerf_scene::dataset::read_split(data_dir, nerf_scene::dataset::Split::Train)?;
    let first = frames
        .first()
        .with_context(|| format!("{}: no training frames", data_dir.display()))?;
    Ok(match &first.camera {
        Camera::Colmap(c) => c.size,
        _ => {
            let (w, h) = image::image_dimensions(&first.file_path)
                .with_context(|| format!("size of {}", first.file_path.display()))?;
            (w as usize, h as usize)
        }
    })
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
    pub(crate) fn camera(&self) -> PerspectiveCamera {
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
    /// `DataCameraConfig::camera`). An error when the config has none.
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
    pub(crate) fn dataset_stem(&self) -> String {
        self.data.dataset_stem()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn downscale_gives_the_photos_size_over_n_within_the_limit() {
        let (dir, json) = nerf_files::test_files::temp_file("transforms.json");
        let frame = |z: f64| {
            format!(
                r#"{{"file_path": "{z}.jpg", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,{z}],[0,0,0,1]]}}"#
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
            image_size: Some([8, 8]),
            dataset_name: None,
            data_dir: None,
            cameras: None,
            downscale: None,
            pixel_budget: None,
        };
        let size = |d: &DataConfig, usage| d.dataset_image_size(dir.path(), usage);
        assert_eq!(size(&data, SizeUse::Training).unwrap(), (8, 8));
        data.downscale = Some(50.0);
        assert_eq!(size(&data, SizeUse::Scoring).unwrap(), (2000, 1200));
        data.downscale = Some(2.0);
        let err = size(&data, SizeUse::Training).unwrap_err().to_string();
        assert!(err.contains("50000x30000") && err.contains("4096"), "{err}");
        // Without a size: training within the budget, scoring at the photos' own size
        // (here over the side limit, so an error).
        data.downscale = None;
        data.image_size = None;
        data.pixel_budget = Some(1_000_000);
        // 100000 × 60000 / n² ≤ 1e6 first at n = 78 (1282 × 769).
        assert_eq!(size(&data, SizeUse::Training).unwrap(), (1282, 769));
        let err = size(&data, SizeUse::Scoring).unwrap_err().to_string();
        assert!(err.contains("100000x60000"), "{err}");
    }

    #[test]
    fn scale_factor_is_the_smallest_that_fits_the_budget() {
        let budget = 640 * 480;
        assert_eq!(photo_scale_factor((200, 200), budget), 1);
        assert_eq!(photo_scale_factor((640, 480), budget), 1);
        assert_eq!(photo_scale_factor((641, 480), budget), 2);
        // 1536 × 1024 = 1.57 M: 1/2 is 393 k, 1/3 is 175 k.
        assert_eq!(photo_scale_factor((1536, 1024), budget), 3);
        assert_eq!(photo_scale_factor((1920, 1080), budget), 3);
        assert_eq!(photo_scale_factor((1080, 1920), budget), 3);
        for (w, h) in [(3000, 2000), (4032, 3024), (7, 5), (10_000, 1)] {
            for b in [1, 100, 12_345, 307_200] {
                let n = photo_scale_factor((w, h), b);
                let px = |n: usize| (w as f64 / n as f64) * (h as f64 / n as f64);
                assert!(px(n) <= b as f64, "{w}x{h} budget {b}: 1/{n}");
                assert!(n == 1 || px(n - 1) > b as f64, "{w}x{h} budget {b}: 1/{n}");
            }
        }
    }
}
