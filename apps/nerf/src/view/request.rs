//! The viewer's `/render.png` query, `eye=x,y,z&at=x,y,z&up=x,y,z&focal=F&width=W&height=H`
//! (plus the page's `client` and `gen`), checked and turned into a camera. Every problem is a
//! message for a 400 reply that names the bound it broke.
//!
//! The bounds, so that every accepted camera renders a meaningful picture in f32:
//! * every coordinate of `eye`, `at` and `up` finite and at most [`MAX_COORDINATE`] (1e4) in
//!   size — ray origins are f32, whose spacing at 1e4 is already 1e-3 of a scene unit;
//! * `|eye − at|` at least [`MIN_DISTANCE`] (1e-6): the camera must look somewhere;
//! * `up` not parallel to the view direction: the sine of the angle between them at least
//!   [`MIN_UP_SINE`] (1e-3, about 0.06°), else the camera's roll is undefined;
//! * `focal` (NDC) from [`MIN_FOCAL`] to [`MAX_FOCAL`] (1e-3 to 1e3: a field of view from
//!   179.9° down to 0.11°; outside it the rays of neighbouring pixels are no longer distinct in
//!   f32, or all leave at the image plane's edge);
//! * `width` and `height` whole numbers from 1 to `limits::IMAGE_SIDE` (4096);
//! * `client` 1 to 64 characters, `gen` a whole number.

use glam::DVec3;

use nerf::config::limits;
use nerf::core::camera::{look_at_view_transform, PerspectiveCamera};

/// What a query leaves out: the config's first surround camera and image size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewDefaults {
    /// Camera position.
    pub eye: DVec3,
    /// Point looked at.
    pub at: DVec3,
    /// Up direction.
    pub up: DVec3,
    /// NDC focal length.
    pub focal: f64,
    /// Image width.
    pub width: usize,
    /// Image height.
    pub height: usize,
}

/// A checked view request.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewRequest {
    /// The pytorch3d camera (`look_at_view_transform(eye, at, up)`, NDC focal on both axes, as
    /// the surround cameras).
    pub camera: PerspectiveCamera,
    /// Image width.
    pub width: usize,
    /// Image height.
    pub height: usize,
    /// The page that asked (its newer requests make this one stale), if any.
    pub client: Option<String>,
    /// The request's number among its client's; higher is newer.
    pub generation: u64,
}

/// Largest coordinate accepted in `eye`, `at` and `up`: ray origins are f32, whose spacing at
/// 1e4 is 1e-3 (a thousandth of the unit-sized scenes).
pub const MAX_COORDINATE: f64 = 1e4;

/// Smallest distance between `eye` and `at`.
pub const MIN_DISTANCE: f64 = 1e-6;

/// Smallest sine of the angle between `up` and the view direction `at − eye`.
pub const MIN_UP_SINE: f64 = 1e-3;

/// Smallest NDC focal length (a field of view of 179.9°).
pub const MIN_FOCAL: f64 = 1e-3;

/// Largest NDC focal length (a field of view of 0.11°; the rays of neighbouring pixels of a
/// 4096-pixel image then still differ in f32).
pub const MAX_FOCAL: f64 = 1e3;

/// Parses `x,y,z` into a vector of three finite numbers of size at most [`MAX_COORDINATE`].
fn vec3(key: &str, text: &str) -> Result<DVec3, String> {
    let usable = |v: f64| v.is_finite() && v.abs() <= MAX_COORDINATE;
    let parts: Vec<Result<f64, _>> = text.split(',').map(|p| p.trim().parse::<f64>()).collect();
    match parts.as_slice() {
        [Ok(x), Ok(y), Ok(z)] if usable(*x) && usable(*y) && usable(*z) => {
            Ok(DVec3::new(*x, *y, *z))
        }
        _ => Err(format!(
            "{key}: expected three finite numbers x,y,z of magnitude at most {MAX_COORDINATE:e} (got {text:?})"
        )),
    }
}

/// Parses an NDC focal length in `MIN_FOCAL..=MAX_FOCAL`.
fn focal(text: &str) -> Result<f64, String> {
    text.trim()
        .parse::<f64>()
        .ok()
        .filter(|f| (MIN_FOCAL..=MAX_FOCAL).contains(f))
        .ok_or_else(|| {
            format!("focal: must be a number from {MIN_FOCAL:e} to {MAX_FOCAL:e} (got {text:?})")
        })
}

/// Checks that `eye`, `at` and `up` make a camera with a defined view direction and roll.
fn check_pose(eye: DVec3, at: DVec3, up: DVec3) -> Result<(), String> {
    let distance = (at - eye).length();
    if distance < MIN_DISTANCE {
        return Err(format!(
            "eye and at must differ by at least {MIN_DISTANCE:e} (the camera would look nowhere; they are {distance:e} apart)"
        ));
    }
    if up.length() < MIN_DISTANCE {
        return Err(format!(
            "up must be a non-zero vector (length at least {MIN_DISTANCE:e})"
        ));
    }
    let sine = (at - eye).normalize().cross(up.normalize()).length();
    if sine < MIN_UP_SINE {
        return Err(format!(
            "up must not be parallel to the view direction at - eye (the sine of their angle is {sine:.1e}, at least {MIN_UP_SINE:e} needed)"
        ));
    }
    Ok(())
}

/// Parses an image side in `1..=limits::IMAGE_SIDE`.
fn side(key: &str, text: &str) -> Result<usize, String> {
    match text.trim().parse::<usize>() {
        Ok(v) if (1..=limits::IMAGE_SIDE).contains(&v) => Ok(v),
        _ => Err(format!(
            "{key}: must be a whole number from 1 to {} (got {text:?})",
            limits::IMAGE_SIDE
        )),
    }
}

/// Parses the query's `(key, value)` pairs; unknown or repeated keys are errors too, so a typo
/// is not silently replaced by a default.
pub fn parse_view_query(
    pairs: &[(String, String)],
    defaults: &ViewDefaults,
) -> Result<ViewRequest, String> {
    let mut d = *defaults;
    let (mut client, mut generation) = (None, 0);
    let mut seen = Vec::new();
    for (key, value) in pairs {
        if seen.contains(&key.as_str()) {
            return Err(format!("{key}: given more than once"));
        }
        seen.push(key.as_str());
        match key.as_str() {
            "eye" => d.eye = vec3(key, value)?,
            "at" => d.at = vec3(key, value)?,
            "up" => d.up = vec3(key, value)?,
            "focal" => d.focal = focal(value)?,
            "width" => d.width = side(key, value)?,
            "height" => d.height = side(key, value)?,
            "client" if value.len() <= 64 && !value.is_empty() => client = Some(value.clone()),
            "client" => return Err("client: must be 1 to 64 characters".into()),
            "gen" => {
                generation = value
                    .parse()
                    .map_err(|_| format!("gen: must be a whole number (got {value:?})"))?
            }
            _ => return Err(format!("unknown parameter {key:?} (expected eye, at, up, focal, width, height, client, gen)")),
        }
    }
    check_pose(d.eye, d.at, d.up)?;
    // A focal left out is the viewer's default: the config's `cameras.focal_length`, or the
    // checkpoint's stored capture path, whichever the viewer started from.
    if !(MIN_FOCAL..=MAX_FOCAL).contains(&d.focal) {
        return Err(format!(
            "focal: must be from {MIN_FOCAL:e} to {MAX_FOCAL:e} (the viewer's default focal \
             length, from the config or the checkpoint's capture path, is {})",
            nerf::core::term::short_number(d.focal)
        ));
    }
    let (r, t) = look_at_view_transform(d.eye, d.at, d.up);
    let camera = PerspectiveCamera::new(r, t, d.focal);
    camera.validate().map_err(|e| e.to_string())?;
    Ok(ViewRequest {
        camera,
        width: d.width,
        height: d.height,
        client,
        generation,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn defaults() -> ViewDefaults {
        ViewDefaults {
            eye: DVec3::new(0.0, 0.0, -3.0),
            at: DVec3::ZERO,
            up: DVec3::Y,
            focal: 1.0,
            width: 64,
            height: 48,
        }
    }

    fn parse(query: &[(&str, &str)]) -> Result<ViewRequest, String> {
        let pairs: Vec<(String, String)> = query
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        parse_view_query(&pairs, &defaults())
    }

    #[test]
    fn a_full_query_is_the_look_at_camera() {
        let req = parse(&[
            ("eye", "0,0,4"),
            ("at", "0,0,0"),
            ("up", "0,1,0"),
            ("focal", "2"),
            ("width", "10"),
            ("height", "20"),
            ("client", "a"),
            ("gen", "7"),
        ])
        .unwrap();
        let (r, t) = look_at_view_transform(DVec3::new(0.0, 0.0, 4.0), DVec3::ZERO, DVec3::Y);
        assert_eq!(req.camera, PerspectiveCamera::new(r, t, 2.0));
        assert_eq!((req.width, req.height, req.generation), (10, 20, 7));
        assert_eq!(req.client.as_deref(), Some("a"));
        // Nothing given: the defaults.
        let req = parse(&[]).unwrap();
        assert_eq!((req.width, req.height, req.client), (64, 48, None));
    }

    #[test]
    fn bad_values_are_named() {
        for (query, key) in [
            (vec![("eye", "1,2")], "eye"),
            (vec![("eye", "nan,0,0")], "eye"),
            (vec![("at", "0,inf,0")], "at"),
            (vec![("eye", "1e300,0,0")], "magnitude"),
            (vec![("eye", "0,0,-10001")], "at most 1e4"),
            (vec![("at", "0,-inf,0")], "at"),
            (vec![("up", "0,NaN,0")], "up"),
            (vec![("up", "0,1e400,0")], "up"),
            (vec![("focal", "1e9")], "focal"),
            (vec![("focal", "1e300")], "from 1e-3 to 1e3"),
            (vec![("focal", "1e-300")], "from 1e-3 to 1e3"),
            (vec![("focal", "0")], "focal"),
            (vec![("focal", "-1")], "focal"),
            (vec![("focal", "nan")], "focal"),
            (vec![("focal", "inf")], "focal"),
            (vec![("width", "0")], "width"),
            (vec![("height", "4097")], "height"),
            (vec![("width", "1e3")], "width"),
            (vec![("eye", "0,0,0")], "eye and at"),
            (vec![("eye", "0,0,1e-7")], "eye and at"),
            (vec![("up", "0,0,0")], "up"),
            // The default eye is on the z axis: an up along z is the view direction.
            (vec![("up", "0,0,1")], "parallel"),
            (vec![("up", "0,0,-5")], "parallel"),
            (vec![("up", "1e-5,0,1")], "parallel"),
            (vec![("zoom", "2")], "unknown parameter"),
            (vec![("eye", "0,0,3"), ("eye", "0,0,4")], "more than once"),
            (vec![("gen", "-1")], "gen"),
        ] {
            let err = parse(&query).unwrap_err();
            assert!(err.contains(key), "{query:?}: {err}");
        }
    }

    #[test]
    fn the_bounds_themselves_are_accepted() {
        for query in [
            vec![("focal", "1e-3")],
            vec![("focal", "1e3")],
            vec![("eye", "0,0,-1e4"), ("at", "1e4,1e4,1e4")],
            vec![("eye", "0,0,1e-6")],
            // sin ≈ 2e-3: nearly along the view direction, but the roll is still defined.
            vec![("up", "2e-3,0,1")],
        ] {
            let req = parse(&query).unwrap_or_else(|e| panic!("{query:?}: {e}"));
            assert!(req.camera.validate().is_ok(), "{query:?}");
        }
    }

    #[test]
    fn defaults_outside_the_bounds_are_refused_too() {
        let mut d = defaults();
        d.focal = 1e-300;
        let err = parse_view_query(&[], &d).unwrap_err();
        assert!(err.contains("focal"), "{err}");
    }

    /// Whatever the query (the known keys and any others, each with values that stress a
    /// parser), parsing returns an error or a usable camera and size; it never panics.
    /// Deterministic: a fixed ChaCha seed and no failure files.
    mod fuzz {
        use super::*;
        use proptest::prelude::*;
        use proptest::test_runner::{RngAlgorithm, RngSeed};

        fn value() -> impl Strategy<Value = String> {
            const SPECIAL: [&str; 6] = [
                "0,0,1",
                "-1",
                "nan,0,0",
                "1e400",
                "18446744073709551616",
                "'ü✓'",
            ];
            prop_oneof![
                prop::sample::select(&SPECIAL[..]).prop_map(str::to_string),
                any::<f64>().prop_map(|v| format!("{v:e}")),
                "[-0-9.,e]{0,20}",
            ]
        }

        proptest! {
            #![proptest_config(ProptestConfig {
                cases: 512,
                rng_algorithm: RngAlgorithm::ChaCha,
                rng_seed: RngSeed::Fixed(0x5eed_2026_0020),
                failure_persistence: None,
                ..ProptestConfig::default()
            })]

            #[test]
            fn view_queries_never_panic(
                pairs in prop::collection::vec((
                    prop_oneof![
                        Just("eye".to_string()), Just("at".to_string()), Just("up".to_string()),
                        Just("focal".to_string()), Just("width".to_string()),
                        Just("height".to_string()), Just("client".to_string()),
                        Just("gen".to_string()), "[ -~]{0,6}",
                    ],
                    value(),
                ), 0..6),
            ) {
                let mut d = defaults();
                d.width = 8;
                d.height = 8;
                if let Ok(request) = parse_view_query(&pairs, &d) {
                    prop_assert!(request.camera.validate().is_ok());
                    prop_assert!(request.width >= 1 && request.height >= 1);
                }
            }
        }
    }
}
