//! Whether a capture's camera can be right: the geometric rules a camera read from a file must
//! meet before anything is trained on it. Finite but impossible values (a focal length of
//! 1e-300 or 1e308, a principal point at 1e300, a distortion of 1e308, a camera of another
//! shape than its photo) otherwise train silently on nothing and score a black render.
//!
//! The rules, derived from what a photograph can be (docs/reliability.md#captures):
//!
//! * **Field of view** across each image axis between `MIN_FIELD_OF_VIEW_DEGREES` and
//!   `MAX_FIELD_OF_VIEW_DEGREES` for a perspective lens, `2·atan(side / 2f)`; a fisheye's
//!   angle `side / f` (its distorted angle `θ_d`) up to `MAX_FISHEYE_FIELD_OF_VIEW_DEGREES`.
//! * **Principal point** within the image, or at most `PRINCIPAL_POINT_MARGIN` of its side
//!   outside it (a cropped photo's centre).
//! * **Distortion** invertible and monotonic over the whole image: at every point of a grid
//!   over the image, corners included, undistortion converges and the lens keeps its
//!   orientation (`LensDistortion::check_invertible_at`), and along each line from the
//!   principal point to the image's edge the undistorted radius keeps rising.
//! * **Size**: the camera's image size equal to its photo's, or the same aspect within
//!   `ASPECT_TOLERANCE` and a scale of at most `MAX_SIZE_RATIO` either way (a camera
//!   calibrated at another resolution, [`check_photo_size`]).

use glam::DVec2;

use crate::camera::CameraError;
use crate::lens::LensDistortion;
use crate::term::short_number;

/// The narrowest field of view across an image axis: a 0.5° lens is a 2,900 mm telephoto on
/// a full-frame sensor.
pub(crate) const MIN_FIELD_OF_VIEW_DEGREES: f64 = 0.5;
/// The widest field of view of a perspective (non-fisheye) lens across an image axis: 180°
/// needs an infinite image plane.
pub(crate) const MAX_FIELD_OF_VIEW_DEGREES: f64 = 179.0;
/// The widest fisheye angle across an image axis (`θ_d` from edge to edge): beyond 300° the
/// lens would see behind itself from both edges.
pub(crate) const MAX_FISHEYE_FIELD_OF_VIEW_DEGREES: f64 = 300.0;
/// How far outside the image the principal point may lie, as a fraction of the image's side.
pub(crate) const PRINCIPAL_POINT_MARGIN: f64 = 0.25;
/// A camera's aspect may differ from its photo's by this fraction (rounding a downscaled side).
pub(crate) const ASPECT_TOLERANCE: f64 = 0.01;
/// A camera may describe its photo at most this many times larger or smaller (`data.downscale`
/// goes to 64).
pub(crate) const MAX_SIZE_RATIO: f64 = 64.0;

/// The farthest a stored capture path (an orbit's radius and height, a spiral's centre, radii
/// and focus distance) may reach in the normalised frame, where the training cameras stand
/// within distance 1 of the centre: from 100 the whole scene is under a pixel.
pub const MAX_NORMALISED_DISTANCE: f64 = 100.0;

/// Grid points along each image axis at which the distortion is checked.
const GRID: usize = 9;
/// Steps along each line from the principal point at which the radius must rise.
const RADIAL_STEPS: usize = 32;

/// Checks a camera's intrinsics against the rules above: `size` `(width, height)` in pixels,
/// `focal` `[fx, fy]` and `principal_point` `[cx, cy]` in pixels, `distortion` on the
/// normalised plane. The error is one line stating the rule broken and the values.
pub fn check_intrinsics(
    (width, height): (usize, usize),
    focal: [f64; 2],
    principal_point: [f64; 2],
    distortion: &LensDistortion,
) -> Result<(), CameraError> {
    let fisheye = distortion.is_fisheye();
    let sides = [width as f64, height as f64];
    for ((axis, side), f) in ["x", "y"].iter().zip(sides).zip(focal) {
        let degrees = field_of_view_degrees(side, f, fisheye);
        let (low, high) = match fisheye {
            false => (MIN_FIELD_OF_VIEW_DEGREES, MAX_FIELD_OF_VIEW_DEGREES),
            true => (MIN_FIELD_OF_VIEW_DEGREES, MAX_FISHEYE_FIELD_OF_VIEW_DEGREES),
        };
        if !(low..=high).contains(&degrees) {
            return Err(CameraError::FieldOfView {
                axis,
                side,
                focal: f,
                degrees,
                fisheye,
                range: [low, high],
            });
        }
    }
    for ((axis, side), c) in ["cx", "cy"].iter().zip(sides).zip(principal_point) {
        let margin = PRINCIPAL_POINT_MARGIN * side;
        if !(-margin..=side + margin).contains(&c) {
            return Err(CameraError::PrincipalPoint {
                axis,
                value: c,
                side,
                margin: PRINCIPAL_POINT_MARGIN,
            });
        }
    }
    check_distortion(sides, focal, principal_point, distortion)
}

/// The field of view in degrees across an image side of `side` pixels at focal length `focal`
/// pixels: `2·atan(side / 2f)` for a perspective lens, `side / f` (radians of `θ_d`) for a
/// fisheye.
pub(crate) fn field_of_view_degrees(side: f64, focal: f64, fisheye: bool) -> f64 {
    match fisheye {
        false => 2.0 * (side / (2.0 * focal)).atan().to_degrees(),
        true => (side / focal).to_degrees(),
    }
}

/// Checks NDC focal lengths `[fx, fy]` (the image spans 2 NDC units) against the field-of-view
/// rule of a perspective lens: `2·atan(1 / f)` from `MIN_FIELD_OF_VIEW_DEGREES` to
/// `MAX_FIELD_OF_VIEW_DEGREES`.
pub fn check_ndc_focal(focal: [f64; 2]) -> Result<(), CameraError> {
    for f in focal {
        let degrees = field_of_view_degrees(2.0, f, false);
        if !(MIN_FIELD_OF_VIEW_DEGREES..=MAX_FIELD_OF_VIEW_DEGREES).contains(&degrees) {
            return Err(CameraError::NdcFieldOfView {
                focal: f,
                degrees,
                range: [MIN_FIELD_OF_VIEW_DEGREES, MAX_FIELD_OF_VIEW_DEGREES],
            });
        }
    }
    Ok(())
}

/// Checks that a stored capture path's `what` (a distance in the normalised frame) is within
/// [`MAX_NORMALISED_DISTANCE`] of the centre.
pub fn check_normalised_distance(what: &str, distance: f64) -> Result<(), CameraError> {
    if distance.is_nan() || distance.abs() > MAX_NORMALISED_DISTANCE {
        return Err(CameraError::Distance {
            what: what.to_string(),
            distance,
            limit: MAX_NORMALISED_DISTANCE,
        });
    }
    Ok(())
}

/// The distortion's rule: invertible on a grid over the image and radially monotonic from the
/// principal point to the edge ([`check_intrinsics`]).
fn check_distortion(
    [width, height]: [f64; 2],
    [fx, fy]: [f64; 2],
    [cx, cy]: [f64; 2],
    distortion: &LensDistortion,
) -> Result<(), CameraError> {
    if *distortion == LensDistortion::NONE {
        return Ok(());
    }
    let normalised = |u: f64, v: f64| DVec2::new((u - cx) / fx, (v - cy) / fy);
    let grid: Vec<DVec2> = (0..GRID)
        .flat_map(|i| (0..GRID).map(move |j| (i, j)))
        .map(|(i, j)| {
            let t = |k: usize, side: f64| side * k as f64 / (GRID - 1) as f64;
            normalised(t(i, width), t(j, height))
        })
        .collect();
    if let Err(why) = distortion.check_invertible_at(&grid) {
        return Err(CameraError::Distortion {
            property: "invertible",
            detail: why,
        });
    }
    // Lines from the principal point to the 4 corners and the 4 edge midpoints.
    let ends = [
        (0.0, 0.0),
        (width, 0.0),
        (0.0, height),
        (width, height),
        (width / 2.0, 0.0),
        (width / 2.0, height),
        (0.0, height / 2.0),
        (width, height / 2.0),
    ];
    for (u, v) in ends {
        let end = normalised(u, v);
        let mut previous = 0.0;
        for step in 1..=RADIAL_STEPS {
            let d = end * (step as f64 / RADIAL_STEPS as f64);
            let radius = match distortion.undistort(d) {
                Some(p) => p.length(),
                // A fisheye ray at 90° or more: the radius on the plane has no meaning; the
                // angle's monotonicity is checked by `check_invertible_at`.
                None => break,
            };
            if radius.is_nan() || radius <= previous {
                return Err(CameraError::Distortion {
                    property: "monotonic",
                    detail: format!(
                        "towards pixel ({u}, {v}) the undistorted radius stops rising at {}",
                        short_number(previous)
                    ),
                });
            }
            previous = radius;
        }
    }
    Ok(())
}

/// Checks that a camera of `camera` `(width, height)` pixels can describe its photo of `photo`
/// pixels: the same size, or the same aspect within `ASPECT_TOLERANCE` at a scale of at most
/// `MAX_SIZE_RATIO` (a camera calibrated at another resolution; the rays follow the scale).
pub fn check_photo_size(camera: (usize, usize), photo: (u32, u32)) -> Result<(), CameraError> {
    if camera == (photo.0 as usize, photo.1 as usize) {
        return Ok(());
    }
    let (cw, ch) = (camera.0 as f64, camera.1 as f64);
    let (pw, ph) = (f64::from(photo.0), f64::from(photo.1));
    let aspect = (cw / ch) / (pw / ph);
    let scale = cw / pw;
    let refuse = |rule: String| {
        Err(CameraError::PhotoSize {
            camera,
            photo,
            rule,
        })
    };
    if (aspect - 1.0).abs() > ASPECT_TOLERANCE {
        return refuse(format!(
            "a camera must have its photo's size or its aspect (here {:.3} against {:.3})",
            cw / ch,
            pw / ph
        ));
    }
    if !(1.0 / MAX_SIZE_RATIO..=MAX_SIZE_RATIO).contains(&scale) {
        return refuse(format!(
            "a camera may describe its photo at most {MAX_SIZE_RATIO} times larger or smaller"
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lens::Fisheye;

    const SIZE: (usize, usize) = (640, 480);
    const CENTRE: [f64; 2] = [320.0, 240.0];

    fn check(focal: [f64; 2], pp: [f64; 2], d: LensDistortion) -> Result<(), String> {
        check_intrinsics(SIZE, focal, pp, &d).map_err(|e| e.to_string())
    }

    #[test]
    fn fields_of_view_follow_the_pinhole_and_fisheye_formulas() {
        // 640 px at f = 320 px: 2·atan(1) = 90°.
        assert!((field_of_view_degrees(640.0, 320.0, false) - 90.0).abs() < 1e-12);
        // A fisheye's θ_d across 640 px at f = 320 px: 2 rad.
        let fisheye = field_of_view_degrees(640.0, 320.0, true);
        assert!((fisheye - 2f64.to_degrees()).abs() < 1e-12);
    }

    #[test]
    fn real_cameras_pass() {
        let none = LensDistortion::NONE;
        assert_eq!(check([500.0, 500.0], CENTRE, none), Ok(()));
        // A phone's wide lens with OpenCV distortion, and a principal point off-centre.
        let wide = LensDistortion::polynomial([-0.12, 0.03, 0.0, 0.0], [1e-3, -1.5e-3]);
        assert_eq!(check([294.0, 294.0], [300.0, 250.0], wide), Ok(()));
        // A GoPro-like fisheye over 170°.
        let fisheye = LensDistortion::Fisheye(Fisheye {
            k: [0.05, -0.01, 0.0, 0.0],
        });
        assert_eq!(check([210.0, 210.0], CENTRE, fisheye), Ok(()));
    }

    #[test]
    fn impossible_fields_of_view_are_refused_with_the_rule() {
        let none = LensDistortion::NONE;
        for focal in [1e-300, 1e308, 0.5, 1e6] {
            let err = check([focal, focal], CENTRE, none).unwrap_err();
            assert!(
                err.contains("field of view") && err.contains("0.5° to 179°"),
                "{err}"
            );
            assert!(err.len() < 200, "{err}");
        }
        // A fisheye may see more than 180°, not more than 300°.
        let fisheye = LensDistortion::Fisheye(Fisheye { k: [0.0; 4] });
        assert_eq!(check([150.0, 150.0], CENTRE, fisheye), Ok(()));
        let err = check([100.0, 100.0], CENTRE, fisheye).unwrap_err();
        assert!(err.contains("fisheye"), "{err}");
    }

    #[test]
    fn a_principal_point_far_outside_the_image_is_refused() {
        let none = LensDistortion::NONE;
        // A quarter of the side outside is a cropped photo; more is not a photo.
        assert_eq!(check([500.0, 500.0], [-150.0, 590.0], none), Ok(()));
        let err = check([500.0, 500.0], [1e300, 240.0], none).unwrap_err();
        assert!(
            err.contains("cx = 1e300") && err.contains("outside"),
            "{err}"
        );
        let err = check([500.0, 500.0], [320.0, -130.0], none).unwrap_err();
        assert!(err.contains("cy = -130"), "{err}");
    }

    #[test]
    fn a_distortion_that_folds_or_cannot_be_inverted_is_refused() {
        // k1 = 1e308: Newton cannot undistort (it used to return its input silently).
        let huge = LensDistortion::polynomial([1e308, 0.0, 0.0, 0.0], [0.0; 2]);
        let err = check([500.0, 500.0], CENTRE, huge).unwrap_err();
        assert!(err.contains("not invertible"), "{err}");
        // Strong barrel distortion that turns back inside the image: r(1 − 0.5 r²) peaks at
        // r = 0.816, and the corners are at r = 1.
        let folding = LensDistortion::polynomial([-0.5, 0.0, 0.0, 0.0], [0.0; 2]);
        let err = check([400.0, 400.0], CENTRE, folding).unwrap_err();
        assert!(err.contains("distortion"), "{err}");
        // The same lens over a narrower field never reaches the fold.
        assert_eq!(check([1000.0, 1000.0], CENTRE, folding), Ok(()));
        // A fisheye whose θ_d turns back: θ(1 − θ²) peaks at θ = 0.577 rad.
        let turning = LensDistortion::Fisheye(Fisheye {
            k: [-1.0, 0.0, 0.0, 0.0],
        });
        assert!(check([300.0, 300.0], CENTRE, turning).is_err());
    }

    #[test]
    fn stored_paths_follow_the_same_field_of_view_and_stay_near_the_cameras() {
        // NDC focal 1: 90°; 2: 53°.
        assert!(check_ndc_focal([1.0, 2.0]).is_ok());
        let err = check_ndc_focal([1e-300, 2.0]).unwrap_err().to_string();
        assert!(err.contains("1e-300") && err.contains("180°"), "{err}");
        assert!(check_ndc_focal([2.0, 1e300]).is_err());
        assert!(check_normalised_distance("orbit radius", 0.9).is_ok());
        let err = check_normalised_distance("orbit radius", 1e300).unwrap_err();
        assert!(
            err.to_string().starts_with("orbit radius 1e300 is beyond"),
            "{err}"
        );
        assert!(check_normalised_distance("orbit height", f64::NAN).is_err());
    }

    #[test]
    fn a_camera_fits_its_photo_at_its_size_or_a_clean_rescale() {
        assert!(check_photo_size((400, 400), (400, 400)).is_ok());
        // Calibrated at full size, photos downscaled (a side rounded).
        assert!(check_photo_size((1920, 1080), (427, 240)).is_ok());
        assert!(check_photo_size((800, 800), (400, 400)).is_ok());
        let err = check_photo_size((400, 100), (400, 400))
            .unwrap_err()
            .to_string();
        assert!(err.contains("400x100") && err.contains("aspect"), "{err}");
        let err = check_photo_size((1 << 31, 1 << 31), (400, 400)).unwrap_err();
        assert!(err.to_string().contains("64 times"), "{err}");
    }
}
