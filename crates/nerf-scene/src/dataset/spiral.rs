//! The views `nerf render` and `nerf view` show of a model trained on a *forward-facing*
//! capture (LLFF's scenes such as fern: the cameras stand on roughly a plane and all look the
//! same way). The orbit of [`super::orbit`] circles the z axis around the normalised frame's
//! origin, which for such a capture is the middle of the camera rig: half of its views look
//! back at where no camera ever looked. Forward-facing captures get instead what nerf-pytorch
//! and nerfstudio render them with: a spiral in the image plane of the mean camera, as wide as
//! the cameras' spread, every view looking at one focus point in front of the rig with the
//! cameras' mean field of view ([`CaptureSpiral`]). Training stores it in the checkpoint
//! ([`CaptureSpiral::to_text`], metadata `capture_spiral`) beside the orbit, which it then
//! takes precedence over; a checkpoint without one keeps its orbit.

use anyhow::{bail, ensure, Result};
use glam::DVec3;

use super::normalize::focus_of_axes;
use super::orbit::mean_ndc_focal;
use crate::dataset::Frame;
use nerf_core::camera::checks::{check_ndc_focal, check_normalised_distance};
use nerf_core::camera::{look_at_view_transform, PerspectiveCamera};
use nerf_core::term::short_number;

/// A capture is forward-facing when every camera's viewing direction lies within this many
/// degrees of the cameras' mean viewing direction. Hand-held forward-facing captures (LLFF's
/// scenes) turn their cameras by a few degrees to 15°; an object walked around, even over a
/// quarter turn only (±45°), or a hemisphere such as lego's (up to 90° and more apart) fails
/// it, and keeps the orbit, which suits a view from every side. 30° (a 60° cone) leaves room
/// for a rig that is aimed by hand without letting a partial orbit count as forward-facing.
pub(crate) const FORWARD_FACING_MAX_ANGLE_DEG: f64 = 30.0;

/// The spiral's radius along each axis of the mean camera is this percentile of the cameras'
/// distances from their mean centre along that axis (nerf-pytorch's choice: a few outlying
/// cameras do not widen it).
pub(crate) const SPREAD_PERCENTILE: f64 = 90.0;

/// Turns the spiral makes over the whole path (in its image plane); its motion along the
/// viewing axis makes one in-and-out cycle over the same path.
pub(crate) const SPIRAL_TURNS: f64 = 2.0;

/// Focus distance (normalised units) when neither depth bounds nor converging optical axes
/// say where the content is: the normaliser put the farthest camera at distance 1 from the
/// rig's centre, so this is the rig's own size. [`CaptureSpiral::min_focus_distance`] may
/// raise it.
pub(crate) const FALLBACK_FOCUS_DISTANCE: f64 = 1.0;

/// The normalised mean of the unit vectors along `directions`; `None` for none, or when they
/// cancel out (cameras looking opposite ways).
fn mean_direction(directions: &[DVec3]) -> Option<DVec3> {
    let sum: DVec3 = directions.iter().map(|d| d.normalize()).sum();
    (sum.length() > 1e-9 * directions.len() as f64).then(|| sum.normalize())
}

/// Whether cameras viewing along `forwards` (one direction per camera, any length) form a
/// forward-facing capture: every direction within [`FORWARD_FACING_MAX_ANGLE_DEG`] of their
/// mean. False for no cameras, or for directions that are zero or not finite.
pub(crate) fn is_forward_facing(forwards: &[DVec3]) -> bool {
    let Some(mean) = mean_direction(forwards) else {
        return false;
    };
    let cos_max = FORWARD_FACING_MAX_ANGLE_DEG.to_radians().cos();
    forwards.iter().all(|f| f.normalize().dot(mean) >= cos_max)
}

/// The `p`-th percentile (0 to 100) of `values`, interpolating linearly between the two
/// nearest ranks (NumPy's default); NaN-free, non-empty input.
fn percentile(mut values: Vec<f64>, p: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    let rank = p / 100.0 * (values.len() - 1) as f64;
    let (below, above) = (rank.floor() as usize, rank.ceil() as usize);
    values[below] + (rank - below as f64) * (values[above] - values[below])
}

/// A spiral of views in front of a forward-facing capture, in its normalised frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CaptureSpiral {
    /// The cameras' mean centre, the spiral's middle.
    pub centre: DVec3,
    /// The cameras' mean viewing direction (unit).
    pub forward: DVec3,
    /// The cameras' mean image-up direction made perpendicular to `forward` (unit).
    pub up: DVec3,
    /// The spiral's half-extents (≥ 0) along the mean camera's right, up and forward axes.
    pub radii: [f64; 3],
    /// Distance (> 0) from `centre` along `forward` to the point every view looks at.
    pub focus_distance: f64,
    /// NDC focal lengths `[f_x, f_y]`: the cameras' mean.
    pub focal: [f64; 2],
}

impl CaptureSpiral {
    /// The spiral for a normalised capture whose training frames are `frames`, or `None` when
    /// they are not forward-facing (`is_forward_facing`) or give none (no frames, up
    /// directions along the viewing direction). `depth_bounds` are the near and far depths
    /// of the scene in the normalised frame when the capture gives them (LLFF's bounds).
    ///
    /// The focus point lies at the depth, in front of the mean camera, that is the first of:
    /// halfway between the depth bounds in disparity (`2 / (1/near + 1/far)`, where near and
    /// far content move equally as the view moves), the depth of the point the optical axes
    /// converge on (least squares), `FALLBACK_FOCUS_DISTANCE`; never nearer than
    /// `CaptureSpiral::min_focus_distance`.
    pub fn from_frames(frames: &[Frame], depth_bounds: Option<[f64; 2]>) -> Option<Self> {
        let axes: Vec<(DVec3, DVec3, DVec3)> = frames
            .iter()
            .map(|f| {
                let (forward, up) = f.camera.viewing_axes();
                (f.camera.center(), forward, up)
            })
            .collect();
        let forwards: Vec<DVec3> = axes.iter().map(|a| a.1).collect();
        if !is_forward_facing(&forwards) {
            return None;
        }
        let forward = mean_direction(&forwards)?;
        let up_sum: DVec3 = axes.iter().map(|a| a.2).sum();
        let up = (up_sum - forward * up_sum.dot(forward)).try_normalize()?;
        let right = forward.cross(up);
        let centre = axes.iter().map(|a| a.0).sum::<DVec3>() / axes.len() as f64;
        let radii = [right, up, forward].map(|axis| {
            let spread = axes.iter().map(|a| (a.0 - centre).dot(axis).abs());
            percentile(spread.collect(), SPREAD_PERCENTILE)
        });
        let converging = || {
            let lines: Vec<(DVec3, DVec3)> = axes.iter().map(|a| (a.0, a.1)).collect();
            focus_of_axes(&lines)
                .map(|p| (p - centre).dot(forward))
                .filter(|d| *d > 0.0)
        };
        let content = match depth_bounds {
            Some([near, far]) if near > 0.0 && far >= near => 2.0 / (1.0 / near + 1.0 / far),
            _ => converging().unwrap_or(FALLBACK_FOCUS_DISTANCE),
        };
        let spiral = Self {
            centre,
            forward,
            up,
            radii,
            focus_distance: content.max(Self::min_focus_distance(radii)),
            focal: mean_ndc_focal(frames),
        };
        spiral.validate().ok()?;
        Some(spiral)
    }

    /// The nearest focus distance for which every view of a spiral with `radii` looks within
    /// [`FORWARD_FACING_MAX_ANGLE_DEG`] of the mean viewing direction: a view stands at most
    /// `hypot(r_right, r_up)` aside and `r_forward` ahead, so the focus must lie
    /// `r_forward + hypot / tan(angle)` ahead. Nearer content would have the views turn
    /// further than the cameras did (a small positive floor keeps a spiral of zero radii, all
    /// cameras at one point, looking ahead).
    pub(crate) fn min_focus_distance(radii: [f64; 3]) -> f64 {
        let aside = radii[0].hypot(radii[1]);
        (radii[2] + aside / FORWARD_FACING_MAX_ANGLE_DEG.to_radians().tan()).max(1e-3)
    }

    /// The mean camera's right direction (unit): `forward × up`.
    pub(crate) fn right(&self) -> DVec3 {
        self.forward.cross(self.up)
    }

    /// The point every view looks at.
    pub fn focus(&self) -> DVec3 {
        self.centre + self.focus_distance * self.forward
    }

    /// Checks the values are finite, the axes unit and perpendicular (to 1e-6), the radii
    /// not negative, the focus distance and focal lengths positive.
    pub(crate) fn validate(&self) -> Result<()> {
        let vectors = [self.centre, self.forward, self.up];
        let numbers = [
            self.radii[0],
            self.radii[1],
            self.radii[2],
            self.focus_distance,
        ];
        ensure!(
            vectors.iter().all(|v| v.is_finite())
                && numbers.iter().chain(&self.focal).all(|v| v.is_finite()),
            "capture spiral values must be finite"
        );
        ensure!(
            (self.forward.length() - 1.0).abs() < 1e-6
                && (self.up.length() - 1.0).abs() < 1e-6
                && self.forward.dot(self.up).abs() < 1e-6,
            "capture spiral axes must be perpendicular unit vectors, got forward {} and up {}",
            short_vector(self.forward),
            short_vector(self.up)
        );
        ensure!(
            self.radii.iter().all(|r| *r >= 0.0),
            "capture spiral radii must not be negative, got {}",
            self.radii.map(short_number).join(" ")
        );
        ensure!(
            self.focus_distance > 0.0,
            "capture spiral focus distance must be positive, got {}",
            short_number(self.focus_distance)
        );
        check_normalised_distance("the spiral's centre", self.centre.length())?;
        for (what, value) in [
            ("the spiral's right radius", self.radii[0]),
            ("the spiral's up radius", self.radii[1]),
            ("the spiral's forward radius", self.radii[2]),
            ("the spiral's focus distance", self.focus_distance),
        ] {
            check_normalised_distance(what, value)?;
        }
        check_ndc_focal(self.focal).map_err(|e| anyhow::anyhow!("the spiral's camera: {e}"))
    }

    /// `n_poses` views along the spiral: view `i` at angle `θ = 2π · SPIRAL_TURNS · i / n`
    /// stands at `centre + r_right cos θ · right + r_up sin θ · up + r_forward sin(θ /
    /// SPIRAL_TURNS) · forward`, looks at [`CaptureSpiral::focus`] with `up` up, and has the
    /// spiral's focal lengths. The first view stands `r_right` right of the centre.
    pub fn cameras(&self, n_poses: usize) -> Vec<PerspectiveCamera> {
        let right = self.right();
        let focus = self.focus();
        let step = 2.0 * std::f64::consts::PI * SPIRAL_TURNS / n_poses.max(1) as f64;
        (0..n_poses)
            .map(|i| {
                let theta = i as f64 * step;
                let eye = self.centre
                    + self.radii[0] * theta.cos() * right
                    + self.radii[1] * theta.sin() * self.up
                    + self.radii[2] * (theta / SPIRAL_TURNS).sin() * self.forward;
                let (r, t) = look_at_view_transform(eye, focus, self.up);
                PerspectiveCamera {
                    focal: self.focal,
                    ..PerspectiveCamera::new(r, t, 1.0)
                }
            })
            .collect()
    }

    /// The spiral as text for a checkpoint's metadata, 15 numbers each written so that it
    /// reads back exactly: the centre, forward and up (3 each), the radii (right, up,
    /// forward), the focus distance, `f_x f_y`.
    pub fn to_text(&self) -> String {
        let values = self
            .centre
            .to_array()
            .into_iter()
            .chain(self.forward.to_array())
            .chain(self.up.to_array())
            .chain(self.radii)
            .chain([self.focus_distance])
            .chain(self.focal);
        values
            .map(|v| format!("{v:?}"))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// Reads [`CaptureSpiral::to_text`]; an error for anything but 15 numbers that
    /// `CaptureSpiral::validate` accepts.
    pub fn from_text(text: &str) -> Result<Self> {
        let values = super::orbit::number_list(text)?;
        let Ok(v) = <[f64; 15]>::try_from(values.as_slice()) else {
            bail!(
                "expected 15 numbers (centre, forward, up, radii, focus distance, f_x f_y), \
                 got {}",
                values.len()
            );
        };
        let vector = |i: usize| DVec3::new(v[i], v[i + 1], v[i + 2]);
        let spiral = Self {
            centre: vector(0),
            forward: vector(3),
            up: vector(6),
            radii: [v[9], v[10], v[11]],
            focus_distance: v[12],
            focal: [v[13], v[14]],
        };
        spiral.validate()?;
        Ok(spiral)
    }
}

/// A vector for a one-line message, each coordinate short (`(1e300, 0, 1)`).
fn short_vector(v: DVec3) -> String {
    format!("({})", v.to_array().map(short_number).join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat3;
    use nerf_core::camera::Camera;
    use nerf_core::camera::{ColmapCamera, ColmapPose};
    use nerf_core::lens::LensDistortion;

    /// A capture frame: a 200×100 pinhole of focal 150 px at `eye`, looking along `forward`
    /// with image up as near `up` as it can be.
    fn frame(eye: DVec3, forward: DVec3, up: DVec3) -> Frame {
        let z = forward.normalize();
        let x = z.cross(-up).normalize(); // right = forward × down
        let y = z.cross(x); // down
        let rotation = DMat3::from_cols(x, y, z).transpose();
        let camera = ColmapCamera {
            pose: ColmapPose {
                rotation,
                translation: -(rotation * eye),
            },
            size: (200, 100),
            focal: [150.0, 150.0],
            principal_point: [100.0, 50.0],
            distortion: LensDistortion::polynomial([0.0; 4], [0.0; 2]),
        };
        Frame {
            file_path: "x.png".into(),
            camera: camera.into(),
            mask_path: None,
        }
    }

    /// A forward-facing rig: a 4×3 grid of cameras on the plane y = 0 (x across 1.2, z
    /// across 0.6), looking along +y, each turned by up to 12° (a different way each).
    fn forward_facing() -> Vec<Frame> {
        (0..12)
            .map(|i| {
                let eye = DVec3::new(
                    -0.6 + 0.4 * (i % 4) as f64,
                    0.0,
                    -0.3 + 0.3 * (i / 4) as f64,
                );
                let a = i as f64 * 2.4;
                let turn = 0.2 * (i as f64 / 11.0);
                let forward = DVec3::new(turn * a.cos(), 1.0, turn * a.sin());
                frame(eye, forward, DVec3::Z)
            })
            .collect()
    }

    /// A surround capture: cameras on a ring at height 0.5 around the origin, all looking at
    /// it, as lego's are.
    fn surround() -> Vec<Frame> {
        (0..12)
            .map(|i| {
                let a = i as f64 / 12.0 * std::f64::consts::TAU;
                let eye = DVec3::new(a.cos(), a.sin(), 0.5);
                frame(eye, -eye, DVec3::Z)
            })
            .collect()
    }

    fn forwards(frames: &[Frame]) -> Vec<DVec3> {
        frames.iter().map(|f| f.camera.viewing_axes().0).collect()
    }

    #[test]
    fn forward_facing_rigs_pass_and_surround_captures_fail() {
        assert!(is_forward_facing(&forwards(&forward_facing())));
        assert!(!is_forward_facing(&forwards(&surround())));
        // A quarter turn around an object (±45° from the mean) is not forward-facing.
        let quarter: Vec<DVec3> = (0..10)
            .map(|i| {
                let a = (i as f64 / 9.0 - 0.5) * std::f64::consts::FRAC_PI_2;
                DVec3::new(a.sin(), a.cos(), 0.0)
            })
            .collect();
        assert!(!is_forward_facing(&quarter));
        // One camera turned past the cone spoils a rig; one just inside does not.
        let turned = |deg: f64| {
            let a = deg.to_radians();
            let mut dirs = vec![DVec3::Y; 30];
            dirs.push(DVec3::new(a.sin(), a.cos(), 0.0));
            is_forward_facing(&dirs)
        };
        assert!(turned(30.0) && !turned(33.0));
        assert!(!is_forward_facing(&[]));
        assert!(!is_forward_facing(&[DVec3::Y, -DVec3::Y]));
        assert!(!is_forward_facing(&[DVec3::Y, DVec3::ZERO]));
        // A surround capture gives no spiral.
        assert_eq!(CaptureSpiral::from_frames(&surround(), None), None);
    }

    #[test]
    fn the_spiral_stays_within_the_cameras_spread_and_looks_at_a_point_in_front() {
        let frames = forward_facing();
        let spiral = CaptureSpiral::from_frames(&frames, Some([2.0, 6.0])).unwrap();
        let (forward, right, up) = (spiral.forward, spiral.right(), spiral.up);
        // The cameras' extent along each axis of the mean camera, from their mean centre.
        let centres: Vec<DVec3> = frames.iter().map(|f| f.camera.center()).collect();
        let centre = centres.iter().sum::<DVec3>() / centres.len() as f64;
        assert!((spiral.centre - centre).length() < 1e-12);
        let extent = [right, up, forward].map(|axis| {
            centres
                .iter()
                .map(|c| (*c - centre).dot(axis).abs())
                .fold(0.0, f64::max)
        });
        // Disparity halfway between the bounds: 2 / (1/2 + 1/6) = 3.
        assert!((spiral.focus_distance - 3.0).abs() < 1e-12);
        let cos_cone = FORWARD_FACING_MAX_ANGLE_DEG.to_radians().cos();
        let cameras = spiral.cameras(40);
        assert_eq!(cameras.len(), 40);
        let mut reached = [0.0f64; 3];
        for (i, cam) in cameras.iter().enumerate() {
            let offset = cam.center() - centre;
            for (k, axis) in [right, up, forward].iter().enumerate() {
                let along = offset.dot(*axis).abs();
                assert!(
                    along <= extent[k] + 1e-12,
                    "{i}: axis {k}: {along} > {}",
                    extent[k]
                );
                reached[k] = reached[k].max(along);
            }
            // The centre pixel's ray goes through the focus point, ahead of the view.
            let (o, d) = Camera::from(*cam).ray_through_ndc(0.0, 0.0);
            let to_focus = spiral.focus() - o;
            assert!(to_focus.cross(d).length() < 1e-9 * to_focus.length(), "{i}");
            assert!(to_focus.dot(d) > 0.0, "{i}");
            assert!(d.normalize().dot(forward) >= cos_cone, "{i}: {d}");
            // The top of the picture is the spiral's up.
            let (_, top) = Camera::from(*cam).ray_through_ndc(0.0, 0.5);
            assert!((top - d).dot(up) > 0.0, "{i}");
            assert_eq!(cam.focal, spiral.focal);
        }
        // The spiral spans most of the spread, not a point.
        for k in 0..2 {
            assert!(
                reached[k] > 0.5 * extent[k],
                "axis {k}: {reached:?} of {extent:?}"
            );
        }
        // The focus is in front of every training camera, within its field of view's cone.
        for f in &frames {
            let (cam_forward, _) = f.camera.viewing_axes();
            assert!((spiral.focus() - f.camera.center()).dot(cam_forward) > 0.0);
        }
        // The mean field of view: 150 px over half of 200 across and of 100 down.
        assert_eq!(spiral.focal, [1.5, 3.0]);
    }

    #[test]
    fn the_focus_depth_comes_from_bounds_then_converging_axes_then_the_fallback() {
        // Converging: every camera of the rig looks at (0.1, 4, 0.2).
        let target = DVec3::new(0.1, 4.0, 0.2);
        let converging: Vec<Frame> = forward_facing()
            .iter()
            .map(|f| {
                let eye = f.camera.center();
                frame(eye, target - eye, DVec3::Z)
            })
            .collect();
        let spiral = CaptureSpiral::from_frames(&converging, None).unwrap();
        let expected = (target - spiral.centre).dot(spiral.forward);
        assert!((spiral.focus_distance - expected).abs() < 1e-9);
        // Bounds win over the axes.
        let spiral = CaptureSpiral::from_frames(&converging, Some([1.0, 1.0])).unwrap();
        assert_eq!(
            spiral.focus_distance,
            1.0f64.max(CaptureSpiral::min_focus_distance(spiral.radii))
        );
        // Parallel axes, no bounds: the fallback, raised to keep the views inside the cone.
        let parallel: Vec<Frame> = forward_facing()
            .iter()
            .map(|f| frame(f.camera.center(), DVec3::Y, DVec3::Z))
            .collect();
        let spiral = CaptureSpiral::from_frames(&parallel, None).unwrap();
        let floor = CaptureSpiral::min_focus_distance(spiral.radii);
        assert_eq!(spiral.focus_distance, FALLBACK_FOCUS_DISTANCE.max(floor));
        assert!(floor > FALLBACK_FOCUS_DISTANCE, "{floor}");
        // Content nearer than the floor would turn the views past the cone: the floor wins.
        let spiral = CaptureSpiral::from_frames(&parallel, Some([0.01, 0.02])).unwrap();
        assert_eq!(spiral.focus_distance, floor);
        let cos_cone = FORWARD_FACING_MAX_ANGLE_DEG.to_radians().cos();
        for cam in spiral.cameras(24) {
            let (_, d) = Camera::from(cam).ray_through_ndc(0.0, 0.0);
            assert!(d.normalize().dot(spiral.forward) >= cos_cone - 1e-12);
        }
    }

    #[test]
    fn text_round_trip_and_bad_values() {
        let spiral = CaptureSpiral::from_frames(&forward_facing(), Some([0.7, 9.1])).unwrap();
        assert_eq!(CaptureSpiral::from_text(&spiral.to_text()).unwrap(), spiral);
        let text = |edit: &dyn Fn(&mut Vec<String>)| {
            let mut words: Vec<String> = spiral.to_text().split(' ').map(String::from).collect();
            edit(&mut words);
            words.join(" ")
        };
        for (bad, says) in [
            (text(&|w| w.truncate(14)), "15 numbers"),
            (text(&|w| w.push("1".into())), "15 numbers"),
            (text(&|w| w[0] = "x".into()), "number"),
            (text(&|w| w[1] = "NaN".into()), "finite"),
            (text(&|w| w[3] = "2".into()), "unit"),
            (text(&|w| w[9] = "-0.1".into()), "radii"),
            (text(&|w| w[12] = "0".into()), "focus"),
            (text(&|w| w[14] = "-1".into()), "focal"),
        ] {
            let err = CaptureSpiral::from_text(&bad).unwrap_err().to_string();
            assert!(err.contains(says), "{bad}: {err}");
        }
    }
}
