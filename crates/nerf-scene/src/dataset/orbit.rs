//! The views `nerf render` and `nerf view` show of a model trained on a capture: an orbit
//! that suits the capture's normalised frame (cameras around the origin, up +z, the farthest
//! at distance 1) rather than the homework's surround cameras at radius 4, which stand far
//! outside it. The orbit circles the z axis at the training cameras' mean horizontal distance
//! and mean height, looks at the origin (where the normaliser put the point the cameras look
//! at), and has the cameras' mean field of view. Training stores it in the checkpoint
//! ([`CaptureOrbit::to_text`], metadata `capture_orbit`) beside the scene transform.

use anyhow::{bail, ensure, Result};
use glam::DVec3;

use crate::dataset::Frame;
use nerf_core::camera::checks::{check_ndc_focal, check_normalised_distance};
use nerf_core::camera::{look_at_view_transform, PerspectiveCamera};
use nerf_core::term::short_number;

/// A circle of views around the z axis, looking at the origin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureOrbit {
    /// Distance of the views from the z axis (> 0).
    pub radius: f64,
    /// Height of the views (their z).
    pub height: f64,
    /// NDC focal lengths `[f_x, f_y]`: pixel focal over half the image width and height.
    pub focal: [f64; 2],
}

/// The mean NDC focal lengths `[f_x, f_y]` of `frames`' cameras: a pinhole frame's own, a
/// capture camera's pixel focal over half its image width and height (`[0, 0]` for no frames).
pub(crate) fn mean_ndc_focal(frames: &[Frame]) -> [f64; 2] {
    let n = frames.len() as f64;
    frames.iter().fold([0.0; 2], |sum, f| {
        let f = f.camera.ndc_focal();
        [sum[0] + f[0] / n, sum[1] + f[1] / n]
    })
}

impl CaptureOrbit {
    /// The orbit for a normalised capture whose frames are `frames`: the mean horizontal
    /// distance and height of their centres, and their mean NDC focal lengths (a pinhole
    /// frame's own; a capture camera's pixel focal over half its image size). An error when
    /// there are no frames or the cameras all stand on the z axis.
    pub fn from_frames(frames: &[Frame]) -> Result<Self> {
        ensure!(!frames.is_empty(), "no cameras to place an orbit by");
        let n = frames.len() as f64;
        let centres: Vec<DVec3> = frames.iter().map(|f| f.camera.center()).collect();
        let radius = centres.iter().map(|c| c.x.hypot(c.y)).sum::<f64>() / n;
        let height = centres.iter().map(|c| c.z).sum::<f64>() / n;
        let orbit = Self {
            radius,
            height,
            focal: mean_ndc_focal(frames),
        };
        orbit.validate()?;
        Ok(orbit)
    }

    /// The orbit for a capture checkpoint that stores none (written before orbits were
    /// stored): the normalised frame puts the farthest camera at distance 1, so a circle of
    /// radius 0.9 at height 0.4 (about 24° up), with an NDC focal length of 2 (53° across).
    pub fn normalised_default() -> Self {
        Self {
            radius: 0.9,
            height: 0.4,
            focal: [2.0, 2.0],
        }
    }

    /// Checks the values are finite, the radius positive, radius and height within
    /// [`MAX_NORMALISED_DISTANCE`](nerf_core::camera::checks::MAX_NORMALISED_DISTANCE) and
    /// the focal lengths a lens's ([`check_ndc_focal`]): the rules a capture's own cameras
    /// follow, so that a checkpoint's stored orbit cannot render black frames.
    pub(crate) fn validate(&self) -> Result<()> {
        let values = [self.radius, self.height, self.focal[0], self.focal[1]];
        ensure!(
            values.iter().all(|v| v.is_finite()),
            "capture orbit values must be finite, got {}",
            values.map(short_number).join(" ")
        );
        ensure!(
            self.radius > 1e-6,
            "the capture's cameras stand on the z axis (mean distance from it {}): no orbit",
            short_number(self.radius)
        );
        check_normalised_distance("the orbit's radius", self.radius)?;
        check_normalised_distance("the orbit's height", self.height)?;
        check_ndc_focal(self.focal).map_err(|e| anyhow::anyhow!("the orbit's camera: {e}"))
    }

    /// `n_poses` views evenly around the orbit, the first at azimuth 0 (on +x), each looking
    /// at the origin with +z up.
    pub fn cameras(&self, n_poses: usize) -> Vec<PerspectiveCamera> {
        let step = 2.0 * std::f64::consts::PI / n_poses.max(1) as f64;
        (0..n_poses)
            .map(|i| {
                let azimuth = i as f64 * step;
                let eye = DVec3::new(
                    self.radius * azimuth.cos(),
                    self.radius * azimuth.sin(),
                    self.height,
                );
                let (r, t) = look_at_view_transform(eye, DVec3::ZERO, DVec3::Z);
                PerspectiveCamera {
                    focal: self.focal,
                    ..PerspectiveCamera::new(r, t, 1.0)
                }
            })
            .collect()
    }

    /// The orbit as text for a checkpoint's metadata: `radius height f_x f_y`, each written
    /// so that it reads back exactly.
    pub fn to_text(&self) -> String {
        format!(
            "{:?} {:?} {:?} {:?}",
            self.radius, self.height, self.focal[0], self.focal[1]
        )
    }

    /// Reads [`CaptureOrbit::to_text`]; an error for anything but four numbers that
    /// `CaptureOrbit::validate` accepts.
    pub fn from_text(text: &str) -> Result<Self> {
        let values = number_list(text)?;
        let [radius, height, fx, fy] = values[..] else {
            bail!(
                "expected 4 numbers (radius height f_x f_y), got {}",
                values.len()
            );
        };
        let orbit = Self {
            radius,
            height,
            focal: [fx, fy],
        };
        orbit.validate()?;
        Ok(orbit)
    }
}

/// The numbers of a metadata text (whitespace-separated); an error naming the first that
/// does not parse.
pub(crate) fn number_list(text: &str) -> Result<Vec<f64>> {
    text.split_whitespace()
        .map(str::parse)
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| anyhow::anyhow!("not a number list ({e})"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nerf_core::camera::Camera;
    use nerf_core::camera::{ColmapCamera, ColmapPose};
    use nerf_core::lens::LensDistortion;

    /// A capture camera at `centre` looking at the origin, `focal` px for a `size` image.
    fn frame(centre: DVec3, focal: f64, size: (usize, usize)) -> Frame {
        let (r, t) = look_at_view_transform(centre, DVec3::ZERO, DVec3::Z);
        let pinhole = PerspectiveCamera::new(r, t, 1.0);
        // OpenCV axes: x right, y down, z forward; pytorch3d's: x left, y up, z forward.
        // pytorch3d's world → view rotation is Rᵀ, glam's from_cols_array_2d(R).
        let p3d = glam::DMat3::from_cols_array_2d(&pinhole.r);
        let flip = glam::DMat3::from_diagonal(DVec3::new(-1.0, -1.0, 1.0));
        let rotation = flip * p3d;
        let camera = ColmapCamera {
            pose: ColmapPose {
                rotation,
                translation: -(rotation * centre),
            },
            size,
            focal: [focal, focal],
            principal_point: [size.0 as f64 / 2.0, size.1 as f64 / 2.0],
            distortion: LensDistortion::polynomial([0.0; 4], [0.0; 2]),
        };
        Frame {
            file_path: "x.png".into(),
            camera: camera.into(),
            mask_path: None,
        }
    }

    #[test]
    fn the_orbit_follows_the_cameras_and_looks_at_the_origin() {
        let frames = [
            frame(DVec3::new(0.6, 0.0, 0.3), 100.0, (200, 100)),
            frame(DVec3::new(0.0, -0.8, 0.5), 300.0, (200, 100)),
        ];
        let orbit = CaptureOrbit::from_frames(&frames).unwrap();
        assert!((orbit.radius - 0.7).abs() < 1e-12);
        assert!((orbit.height - 0.4).abs() < 1e-12);
        // Mean of 100/100 and 300/100 across, of 100/50 and 300/50 down.
        assert!((orbit.focal[0] - 2.0).abs() < 1e-12 && (orbit.focal[1] - 4.0).abs() < 1e-12);
        let cameras = orbit.cameras(8);
        assert_eq!(cameras.len(), 8);
        for (i, cam) in cameras.iter().enumerate() {
            let c = cam.center();
            assert!(
                (c.x.hypot(c.y) - 0.7).abs() < 1e-9 && (c.z - 0.4).abs() < 1e-9,
                "{i}"
            );
            // The centre pixel's ray passes through the origin.
            let (o, d) = Camera::from(*cam).ray_through_ndc(0.0, 0.0);
            assert!(o.cross(d).length() < 1e-9, "{i}: {o} {d}");
            assert!(d.dot(-o) > 0.0);
            assert_eq!(cam.focal, orbit.focal);
        }
        // The pixel grid's top row sees above the origin (+z up on screen).
        let (o, d) = Camera::from(cameras[0]).ray_through_ndc(0.0, 0.9);
        let at = o + d * (o.length() / d.dot(-o.normalize()));
        assert!(at.z > 0.0, "{at}");
    }

    #[test]
    fn text_round_trip_and_bad_values() {
        let orbit = CaptureOrbit {
            radius: 0.812_345_678_9,
            height: -0.1,
            focal: [2.777_777_7, 1.5],
        };
        assert_eq!(CaptureOrbit::from_text(&orbit.to_text()).unwrap(), orbit);
        for bad in [
            "",
            "1 2 3",
            "1 2 3 x",
            "0 0 1 1",
            "1 0 -1 1",
            "NaN 0 1 1",
            "1 2 3 4 5",
        ] {
            assert!(CaptureOrbit::from_text(bad).is_err(), "{bad}");
        }
        assert!(CaptureOrbit::from_frames(&[]).is_err());
        CaptureOrbit::normalised_default().validate().unwrap();
    }
}
