//! [`CameraError`]: why a camera cannot image anything, as the camera checks
//! ([`crate::camera::checks`]) and camera validation ([`crate::camera::Camera::validate`])
//! say it. Each variant holds the values it names, and its text is the one-line message the
//! checks have always given (it has no source: nothing further is printed after it).

use crate::term::short_number;

/// A camera that cannot be right: non-finite or degenerate values, a field of view or
/// principal point no lens has, a distortion that cannot be inverted, a size its photo does
/// not have, or a pose too far away. Returned by the functions of
/// [`crate::camera::checks`], [`crate::camera::Camera::validate`] (so
/// [`crate::camera::PerspectiveCamera::validate`] and the COLMAP camera's),
/// [`crate::camera::ColmapPose::from_quaternion`] and
/// `nerf::io::dataset::check_rigid`; a dataset wraps it in
/// `nerf::io::dataset::DatasetError::Camera`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// A value of the pose or intrinsics is NaN or infinite.
    #[error("camera has a non-finite value in {values}")]
    NotFinite {
        /// The values checked, in words (`R, T, focal length or principal point`).
        values: &'static str,
    },
    /// An image of no pixels.
    #[error("camera image size must be positive, got {}×{}", .size.0, .size.1)]
    ImageSize {
        /// `(width, height)` as given.
        size: (usize, usize),
    },
    /// A focal length of zero (a pinhole in NDC) or not positive (in pixels).
    #[error("{}", focal_message(.focal, *.in_pixels))]
    FocalLength {
        /// `[fx, fy]` as given.
        focal: [f64; 2],
        /// Whether the focal lengths are in pixels (they must be positive) rather than NDC
        /// units (they must be non-zero).
        in_pixels: bool,
    },
    /// The rotation is not a proper rotation (not orthonormal, or a mirror).
    #[error(
        "camera rotation is not a proper rotation (|RᵀR − I| = {orthogonality:.2e}, det R = \
         {determinant:.6})"
    )]
    Rotation {
        /// The largest entry of `|RᵀR − I|`.
        orthogonality: f64,
        /// `det R`.
        determinant: f64,
    },
    /// The field of view across an image axis is outside what a lens can have
    /// ([`crate::camera::checks::check_intrinsics`]).
    #[error(
        "a field of view of {}° across {axis} ({side} px at focal length {} px) is not a \
         {}lens's: it must be {}° to {}°",
        short_number(*.degrees),
        short_number(*.focal),
        if *.fisheye { "fisheye " } else { "" },
        .range[0],
        .range[1]
    )]
    FieldOfView {
        /// The image axis, `x` or `y`.
        axis: &'static str,
        /// The image's side along it, in pixels.
        side: f64,
        /// The focal length along it, in pixels.
        focal: f64,
        /// The field of view, in degrees.
        degrees: f64,
        /// Whether the lens is a fisheye (whose angle may pass 180°).
        fisheye: bool,
        /// The fields of view allowed, in degrees.
        range: [f64; 2],
    },
    /// An NDC focal length whose field of view is outside what a lens can have
    /// ([`crate::camera::checks::check_ndc_focal`]).
    #[error(
        "an NDC focal length of {} gives a field of view of {}°: it must be {}° to {}°",
        short_number(*.focal),
        short_number(*.degrees),
        .range[0],
        .range[1]
    )]
    NdcFieldOfView {
        /// The NDC focal length.
        focal: f64,
        /// Its field of view, in degrees.
        degrees: f64,
        /// The fields of view allowed, in degrees.
        range: [f64; 2],
    },
    /// The principal point lies too far outside the image.
    #[error(
        "the principal point's {axis} = {} px lies outside the image (0 to {side} px) by more \
         than {}% of its side",
        short_number(*.value),
        .margin * 100.0
    )]
    PrincipalPoint {
        /// `cx` or `cy`.
        axis: &'static str,
        /// Its value, in pixels.
        value: f64,
        /// The image's side along it, in pixels.
        side: f64,
        /// How far outside the image it may lie, as a fraction of the side.
        margin: f64,
    },
    /// The lens distortion cannot be undone over the whole image.
    #[error("the lens distortion is not {property} over the image: {detail}")]
    Distortion {
        /// What it is not: `invertible` or `monotonic`.
        property: &'static str,
        /// Where and how it fails.
        detail: String,
    },
    /// The camera's image size cannot describe its photo's
    /// ([`crate::camera::checks::check_photo_size`]).
    #[error(
        "the camera is {}x{} but its photo is {}x{}: {rule}",
        .camera.0,
        .camera.1,
        .photo.0,
        .photo.1
    )]
    PhotoSize {
        /// The camera's `(width, height)`.
        camera: (usize, usize),
        /// The photo's `(width, height)`.
        photo: (u32, u32),
        /// The rule broken.
        rule: String,
    },
    /// A stored capture path reaches too far from the normalised frame's centre
    /// ([`crate::camera::checks::check_normalised_distance`]).
    #[error(
        "{what} {} is beyond {limit} in the normalised frame, where the training cameras \
         stand within 1 of the centre",
        short_number(*.distance)
    )]
    Distance {
        /// What the distance is (`orbit radius`, ...).
        what: String,
        /// The distance.
        distance: f64,
        /// The farthest allowed.
        limit: f64,
    },
    /// A pose that is no camera's: a zero quaternion, a camera-to-world matrix that is not
    /// rigid, or one that puts the camera too far away.
    #[error("{message}")]
    Pose {
        /// What is wrong with it.
        message: String,
    },
}

/// The words of [`CameraError::FocalLength`].
fn focal_message(&[fx, fy]: &[f64; 2], in_pixels: bool) -> String {
    match in_pixels {
        true => format!("camera focal lengths must be positive, got fx = {fx}, fy = {fy}"),
        false => "camera focal length must be non-zero".to_string(),
    }
}
