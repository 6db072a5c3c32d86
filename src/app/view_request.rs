//! The viewer's `/render.png` query, `eye=x,y,z&at=x,y,z&up=x,y,z&focal=F&width=W&height=H`
//! (plus the page's `client` and `gen`), checked and turned into a camera. Every problem is a
//! message for a 400 reply.

use glam::DVec3;

use crate::app::config::limits;
use crate::core::camera::{look_at_view_transform, PerspectiveCamera};

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

/// Largest coordinate or focal length accepted: rays are rendered in f32, where much larger
/// positions lose all precision (and past 3.4e38 become infinite).
const MAX_MAGNITUDE: f64 = 1e6;

/// Whether `v` is finite and at most [`MAX_MAGNITUDE`] in size.
fn usable(v: f64) -> bool {
    v.is_finite() && v.abs() <= MAX_MAGNITUDE
}

/// Parses `x,y,z` into a vector of three finite numbers.
fn vec3(key: &str, text: &str) -> Result<DVec3, String> {
    let parts: Vec<Result<f64, _>> = text.split(',').map(|p| p.trim().parse::<f64>()).collect();
    match parts.as_slice() {
        [Ok(x), Ok(y), Ok(z)] if usable(*x) && usable(*y) && usable(*z) => {
            Ok(DVec3::new(*x, *y, *z))
        }
        _ => Err(format!(
            "{key}: expected three finite numbers x,y,z of magnitude at most {MAX_MAGNITUDE:e} (got {text:?})"
        )),
    }
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
            "focal" => {
                d.focal = value
                    .trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|f| usable(*f) && *f > 0.0)
                    .ok_or_else(|| {
                        format!("focal: must be a number > 0 and at most {MAX_MAGNITUDE:e} (got {value:?})")
                    })?
            }
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
    if (d.eye - d.at).length() < 1e-9 {
        return Err("eye and at must differ (the camera would look nowhere)".into());
    }
    if d.up.length() < 1e-9 {
        return Err("up must be a non-zero vector".into());
    }
    let (r, t) = look_at_view_transform(d.eye, d.at, d.up);
    Ok(ViewRequest {
        camera: PerspectiveCamera::new(r, t, d.focal),
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
            (vec![("focal", "1e9")], "focal"),
            (vec![("focal", "0")], "focal"),
            (vec![("focal", "-1")], "focal"),
            (vec![("width", "0")], "width"),
            (vec![("height", "4097")], "height"),
            (vec![("width", "1e3")], "width"),
            (vec![("eye", "0,0,0")], "eye and at"),
            (vec![("up", "0,0,0")], "up"),
            (vec![("zoom", "2")], "unknown parameter"),
            (vec![("eye", "0,0,3"), ("eye", "0,0,4")], "more than once"),
            (vec![("gen", "-1")], "gen"),
        ] {
            let err = parse(&query).unwrap_err();
            assert!(err.contains(key), "{query:?}: {err}");
        }
    }
}
