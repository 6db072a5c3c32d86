//! A `transforms.json` camera's intrinsics keys, as nerfstudio writes them (`camera_model`,
//! `fl_x fl_y cx cy w h`, `k1..k4 p1 p2`) and as instant-ngp's `scripts/colmap2nerf.py`
//! writes them and its `nerf_loader` reads them: `w` and `h` as floats (`1920.0`), the focal
//! length as `fl_x`/`fl_y` or else as a field of view (`camera_angle_x`/`camera_angle_y` in
//! radians, `x_fov`/`y_fov` in degrees), `is_fisheye` for the OpenCV fisheye model, and `cx`,
//! `cy` defaulting to the image centre. Each key stands at the top of the file or in a frame,
//! and the frame's own value wins (the rule of both tools).
//!
//! Keys that describe no camera (colmap2nerf's `fovx`, `fovy`, a frame's `sharpness`) are
//! ignored; instant-ngp's other lens models (`ftheta_p0`, `latlong`, `equirectangular`) are
//! refused by name.

use anyhow::{anyhow, bail, ensure, Result};
use serde::de::IgnoredAny;
use serde::Deserialize;

use nerf_core::camera::NerfstudioIntrinsics;

/// The largest image side (`w`, `h`) taken, in pixels.
pub(crate) const MAX_IMAGE_SIDE: usize = 1 << 20;

/// instant-ngp's lens models that no camera here has: a key of each.
const UNSUPPORTED_LENS_KEYS: [&str; 3] = ["ftheta_p0", "latlong", "equirectangular"];

/// The intrinsics keys of one level of the file (the top or a frame), each optional.
#[derive(Debug, Clone, Default, Deserialize)]
pub(crate) struct Intrinsics {
    camera_model: Option<String>,
    is_fisheye: Option<bool>,
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    camera_angle_x: Option<f64>,
    camera_angle_y: Option<f64>,
    x_fov: Option<f64>,
    y_fov: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    w: Option<f64>,
    h: Option<f64>,
    k1: Option<f64>,
    k2: Option<f64>,
    k3: Option<f64>,
    k4: Option<f64>,
    p1: Option<f64>,
    p2: Option<f64>,
    ftheta_p0: Option<IgnoredAny>,
    latlong: Option<IgnoredAny>,
    equirectangular: Option<IgnoredAny>,
}

/// An image axis, for the keys that come in an x and a y form.
#[derive(Debug, Clone, Copy)]
enum Axis {
    X,
    Y,
}

impl Intrinsics {
    /// An error naming the first key of this level that no camera can take: a `w` or `h`
    /// that is not a whole number of pixels from 1 to [`MAX_IMAGE_SIDE`], a field of view
    /// outside (0, π), or one of instant-ngp's unsupported lens models.
    pub(crate) fn check(&self) -> Result<()> {
        for (key, side) in [("w", self.w), ("h", self.h)] {
            side.map(|v| whole_pixels(v, key)).transpose()?;
        }
        for axis in [Axis::X, Axis::Y] {
            // Any side gives the same verdict on the angle.
            self.focal(axis, 1)?;
        }
        let lens = [&self.ftheta_p0, &self.latlong, &self.equirectangular];
        if let Some((key, _)) = UNSUPPORTED_LENS_KEYS
            .iter()
            .zip(lens)
            .find(|(_, v)| v.is_some())
        {
            bail!(
                "instant-ngp lens `{key}` is not supported (supported: the pinhole with OpenCV \
                 distortion, and is_fisheye: OpenCV fisheye)"
            );
        }
        Ok(())
    }

    /// The complete intrinsics of a frame whose own keys are `self`, in a file whose top-level
    /// keys are `top` (both [`Intrinsics::check`]ed): each key from the frame, else from the
    /// top. The focal length along an axis is the frame's (`fl_x`, else from `camera_angle_x`,
    /// else from `x_fov`), else the top's; a missing `fl_y` is `fl_x`; a missing `cx`, `cy`
    /// the image centre; missing distortion terms 0. An error names the first missing key.
    pub(crate) fn resolve(&self, top: &Intrinsics) -> Result<NerfstudioIntrinsics> {
        let pick = |key: fn(&Intrinsics) -> Option<f64>| key(self).or(key(top));
        let w = pick(|i| i.w).ok_or_else(|| anyhow!("no w"))?;
        let h = pick(|i| i.h).ok_or_else(|| anyhow!("no h"))?;
        let (w, h) = (whole_pixels(w, "w")?, whole_pixels(h, "h")?);
        let fl_x = match self.focal(Axis::X, w)? {
            Some(f) => f,
            None => top
                .focal(Axis::X, w)?
                .ok_or_else(|| anyhow!("no fl_x (nor camera_angle_x, x_fov)"))?,
        };
        let fl_y = match self.focal(Axis::Y, h)? {
            Some(f) => Some(f),
            None => top.focal(Axis::Y, h)?,
        };
        let model = camera_model(
            self.camera_model.as_deref().or(top.camera_model.as_deref()),
            self.is_fisheye.or(top.is_fisheye).unwrap_or(false),
        )?;
        Ok(NerfstudioIntrinsics {
            camera_model: model.to_string(),
            fl_x,
            // nerfstudio and instant-ngp read a missing fl_y as fl_x.
            fl_y: fl_y.unwrap_or(fl_x),
            // instant-ngp's default principal point: the image centre.
            cx: pick(|i| i.cx).unwrap_or(w as f64 / 2.0),
            cy: pick(|i| i.cy).unwrap_or(h as f64 / 2.0),
            w,
            h,
            k: [
                pick(|i| i.k1),
                pick(|i| i.k2),
                pick(|i| i.k3),
                pick(|i| i.k4),
            ]
            .map(|k| k.unwrap_or(0.0)),
            p: [pick(|i| i.p1), pick(|i| i.p2)].map(|p| p.unwrap_or(0.0)),
        })
    }

    /// This level's focal length along `axis` in pixels for an image `side` pixels across:
    /// `fl_`, else from `camera_angle_` (radians), else from `_fov` (degrees); `None` when it
    /// has none of them; an error for a field of view outside (0, π).
    fn focal(&self, axis: Axis, side: usize) -> Result<Option<f64>> {
        let (fl, angle, fov, names) = match axis {
            Axis::X => (
                self.fl_x,
                self.camera_angle_x,
                self.x_fov,
                ["camera_angle_x", "x_fov"],
            ),
            Axis::Y => (
                self.fl_y,
                self.camera_angle_y,
                self.y_fov,
                ["camera_angle_y", "y_fov"],
            ),
        };
        if fl.is_some() {
            return Ok(fl);
        }
        let Some((radians, key, given)) = angle
            .map(|a| (a, names[0], a))
            .or(fov.map(|d| (d.to_radians(), names[1], d)))
        else {
            return Ok(None);
        };
        focal_from_angle(radians, side)
            .map(Some)
            .ok_or_else(|| anyhow!("{key} = {given} is not a field of view in (0, π) radians (0 to 180 degrees for x_fov, y_fov)"))
    }
}

/// The focal length in pixels of a pinhole whose field of view across `side` pixels is
/// `angle` radians: `side / 2 / tan(angle / 2)`; `None` unless `0 < angle < π`.
pub(crate) fn focal_from_angle(angle: f64, side: usize) -> Option<f64> {
    (angle > 0.0 && angle < std::f64::consts::PI).then(|| 0.5 * side as f64 / (0.5 * angle).tan())
}

/// `value` of the key `key` as a whole number of pixels (colmap2nerf writes `w` and `h` as
/// floats: `1920.0`); an error naming the key unless it is one from 1 to [`MAX_IMAGE_SIDE`].
pub(crate) fn whole_pixels(value: f64, key: &str) -> Result<usize> {
    ensure!(
        value.fract() == 0.0 && (1.0..=MAX_IMAGE_SIDE as f64).contains(&value),
        "{key} = {value} is not a whole number of pixels from 1 to {MAX_IMAGE_SIDE}"
    );
    Ok(value as usize)
}

/// The camera model of `camera_model` (nerfstudio's key) and `is_fisheye` (instant-ngp's):
/// `OPENCV` unless either says fisheye; an error when they disagree.
fn camera_model(named: Option<&str>, is_fisheye: bool) -> Result<&str> {
    Ok(match (named, is_fisheye) {
        (None, false) => "OPENCV",
        (None, true) => "OPENCV_FISHEYE",
        (Some(m), true) if m != "OPENCV_FISHEYE" => {
            bail!("is_fisheye is true, but camera_model is {m}")
        }
        (Some(m), _) => m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keys(json: &str) -> Intrinsics {
        serde_json::from_str(json).unwrap()
    }

    #[test]
    fn colmap2nerf_floats_and_fields_of_view_give_the_pinhole() {
        // colmap2nerf's keys for a PINHOLE camera: floats, both focal forms, and fovx.
        let (w, h, f) = (640.0_f64, 480.0_f64, 500.0_f64);
        let angle_x = 2.0 * (w / (2.0 * f)).atan();
        let angle_y = 2.0 * (h / (2.0 * f)).atan();
        let top = keys(&format!(
            r#"{{"w": {w:.1}, "h": {h:.1}, "fl_x": {f}, "fl_y": {f}, "cx": 320.0, "cy": 240.0,
            "camera_angle_x": {angle_x}, "camera_angle_y": {angle_y}, "fovx": 65.2,
            "k1": 0, "k2": 0, "k3": 0, "k4": 0, "p1": 0, "p2": 0, "is_fisheye": false}}"#
        ));
        top.check().unwrap();
        let from_fl = Intrinsics::default().resolve(&top).unwrap();
        assert_eq!((from_fl.w, from_fl.h), (640, 480));
        assert_eq!(from_fl.camera_model, "OPENCV");
        // The angles alone give the same focal lengths (float64 round trip through atan).
        let angles_only = keys(&format!(
            r#"{{"w": {w}, "h": {h}, "camera_angle_x": {angle_x}, "camera_angle_y": {angle_y}}}"#
        ));
        let from_angles = Intrinsics::default().resolve(&angles_only).unwrap();
        assert!((from_angles.fl_x - f).abs() < 1e-9, "{}", from_angles.fl_x);
        assert!((from_angles.fl_y - f).abs() < 1e-9, "{}", from_angles.fl_y);
        // With no cx, cy: the image centre, as instant-ngp defaults.
        assert_eq!([from_angles.cx, from_angles.cy], [320.0, 240.0]);
        // x_fov is in degrees: 90° across 640 pixels is a focal length of 320.
        let fov = keys(r#"{"w": 640, "h": 480, "x_fov": 90}"#);
        let from_fov = Intrinsics::default().resolve(&fov).unwrap();
        assert!((from_fov.fl_x - 320.0).abs() < 1e-9 && from_fov.fl_y == from_fov.fl_x);
    }

    #[test]
    fn a_frames_own_keys_win_over_the_top() {
        let top = keys(r#"{"w": 640.0, "h": 480.0, "fl_x": 500, "cx": 320, "cy": 240}"#);
        // The frame's field of view wins over the top's fl_x: 90° across its own 800.0 px.
        let frame = keys(r#"{"w": 800.0, "h": 600.0, "camera_angle_x": 1.5707963267948966}"#);
        let own = frame.resolve(&top).unwrap();
        assert_eq!((own.w, own.h), (800, 600));
        assert!((own.fl_x - 400.0).abs() < 1e-9 && own.fl_y == own.fl_x);
        assert_eq!([own.cx, own.cy], [320.0, 240.0]);
        let fisheye = keys(r#"{"is_fisheye": true, "k3": 0.01}"#);
        let own = fisheye.resolve(&top).unwrap();
        assert_eq!(own.camera_model, "OPENCV_FISHEYE");
        assert_eq!(own.k, [0.0, 0.0, 0.01, 0.0]);
        assert_eq!(Intrinsics::default().resolve(&top).unwrap().fl_x, 500.0);
    }

    #[test]
    fn bad_keys_are_named() {
        let err = |json: &str| {
            let level = keys(json);
            level
                .check()
                .and_then(|_| Intrinsics::default().resolve(&level).map(|_| ()))
                .unwrap_err()
                .to_string()
        };
        let base = r#""fl_x": 500, "cx": 1, "cy": 1"#;
        let e = err(&format!(r#"{{{base}, "w": 640.5, "h": 480}}"#));
        assert!(
            e.starts_with("w = 640.5 is not a whole number of pixels"),
            "{e}"
        );
        let e = err(&format!(r#"{{{base}, "w": 640, "h": 1e12}}"#));
        assert!(e.starts_with("h = 1000000000000 is not"), "{e}");
        let e = err(&format!(r#"{{{base}, "w": 0, "h": 4}}"#));
        assert!(e.starts_with("w = 0 is not"), "{e}");
        let e = err(r#"{"w": 4, "h": 4, "camera_angle_x": 3.5}"#);
        assert!(
            e.starts_with("camera_angle_x = 3.5 is not a field of view"),
            "{e}"
        );
        let e = err(r#"{"w": 4, "h": 4}"#);
        assert!(e.starts_with("no fl_x"), "{e}");
        let e = err(&format!(r#"{{{base}, "w": 4, "h": 4, "latlong": true}}"#));
        assert!(
            e.contains("instant-ngp lens `latlong` is not supported"),
            "{e}"
        );
        let e = err(&format!(
            r#"{{{base}, "w": 4, "h": 4, "is_fisheye": true, "camera_model": "OPENCV"}}"#
        ));
        assert!(
            e.contains("is_fisheye is true, but camera_model is OPENCV"),
            "{e}"
        );
    }
}
