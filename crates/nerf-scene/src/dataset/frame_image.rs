//! A dataset frame's image file: an RGBA PNG composited onto black or white and resized, with
//! its transparency, read within bounds on the file's size and the decoded image's sides.

use std::path::Path;

use anyhow::{bail, Result};
use image::{ImageBuffer, ImageFormat, Rgba};

use super::dataset_error::{read_dataset_file, DatasetError};
use nerf_core::image::RgbImage;
use nerf_files::decode_budget::{file_decode_cost, reserve};

/// Largest image file read (an 800×800 RGBA PNG is about 0.5 MB; 16-bit 4096² is 128 MB).
pub(crate) const MAX_IMAGE_FILE_BYTES: u64 = 256 << 20;

/// Widest and tallest image file decoded (the NeRF-synthetic renders are 800×800; the f32
/// RGBA copy of an 8192² image is 1 GiB).
pub const MAX_SOURCE_IMAGE_SIDE: u32 = 8192;

/// Reads an RGBA PNG, composites it onto black (or white) and resizes it.
///
/// Returns a `width × height` RGB image, row-major, floats in [0, 1]:
/// `rgb · a + bg · (1 − a)` with `bg` = 0 or 1. Any PNG bit depth or colour type is accepted
/// (no alpha channel means opaque).
///
/// Compositing happens at the file's resolution, then the RGB result is resized
/// ([`super::photo_resize`]: the mean of each block for a whole factor per side, `image`'s
/// `FilterType::Triangle` for any other ratio). Compositing first is equivalent to resizing
/// premultiplied colour, so no dark or bright fringes appear around the object. When the
/// size already matches nothing is resampled.
///
/// Errors (one line, naming the file) for a zero size, a missing file or an undecodable PNG;
/// the last two are a [`DatasetError::MissingFile`] and a [`DatasetError::Photo`] inside the
/// `anyhow::Error` (as [`super::Dataset::load`] returns them).
pub fn load_image(
    path: &Path,
    width: usize,
    height: usize,
    white_background: bool,
) -> Result<RgbImage> {
    Ok(load_image_and_transparency(path, width, height, white_background)?.0)
}

/// [`load_image`], and the image's transparency `1 − a` resized the same way (`width × height`
/// values), so that the image on any other background `b` is `image + transparency · (b − bg)`.
pub fn load_image_and_transparency(
    path: &Path,
    width: usize,
    height: usize,
    white_background: bool,
) -> Result<(RgbImage, Vec<f32>)> {
    let loaded = load_frame_image(path, width, height, white_background)?;
    Ok((loaded.image, loaded.transparency))
}

/// One frame's image as [`load_image_and_transparency`] gives it, with what the file itself was.
#[derive(Debug, Clone)]
pub(crate) struct LoadedImage {
    /// `width × height` composited RGB.
    pub image: RgbImage,
    /// `width × height` transparencies `1 − a`.
    pub transparency: Vec<f32>,
    /// The file's own `(width, height)`, before resizing.
    pub source_size: (u32, u32),
    /// Whether the file has an alpha channel (without one, every pixel is opaque).
    pub has_alpha: bool,
}

/// [`load_image_and_transparency`] with the file's size and whether it has alpha.
pub(crate) fn load_frame_image(
    path: &Path,
    width: usize,
    height: usize,
    white_background: bool,
) -> Result<LoadedImage> {
    let (w, h) = match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) if w > 0 && h > 0 => (w, h),
        _ => bail!(
            "cannot load {} at {width}×{height}: the image size must be positive",
            path.display()
        ),
    };
    // Decoding is counted against the process's budget, so that the images in flight on
    // rayon's threads stay within it however many threads there are.
    let _reservation = reserve(file_decode_cost(path));
    let bytes = read_dataset_file(path, "image", MAX_IMAGE_FILE_BYTES)?;
    // The decoder's sizes come from the file: bounded before it allocates.
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_SOURCE_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_SOURCE_IMAGE_SIDE);
    // PNG or JPEG, by the file's first bytes (captures come as JPEG, renders as PNG).
    let (format, name) = match image::guess_format(&bytes) {
        Ok(ImageFormat::Png) => (ImageFormat::Png, "PNG"),
        Ok(ImageFormat::Jpeg) => (ImageFormat::Jpeg, "JPEG"),
        _ => {
            let message = format!("{} is not a PNG or JPEG image", path.display());
            return Err(DatasetError::photo(path, message).into());
        }
    };
    let mut reader = image::ImageReader::with_format(std::io::Cursor::new(&bytes), format);
    reader.limits(limits);
    let decoded = reader.decode().map_err(|e| {
        let message = format!(
            "cannot decode {name} {}: {}",
            path.display(),
            e.to_string().replace('\n', " ")
        );
        DatasetError::photo(path, message)
    })?;
    let has_alpha = decoded.color().has_alpha();
    // (H0, W0, 4) RGBA in [0, 1]; the decoded copy is dropped at once.
    let mut composited: ImageBuffer<Rgba<f32>, Vec<f32>> = decoded.to_rgba32f();
    drop(decoded);
    let (w0, h0) = composited.dimensions();
    let bg = if white_background { 1.0 } else { 0.0 };
    // Composited colour and transparency, in place; every channel is resized independently
    // and linearly, so the relation between them survives resizing.
    for p in composited.pixels_mut() {
        let a = p[3];
        *p = Rgba([
            p[0] * a + bg * (1.0 - a),
            p[1] * a + bg * (1.0 - a),
            p[2] * a + bg * (1.0 - a),
            1.0 - a,
        ]);
    }
    let resized = super::photo_resize::resize_photo(composited, w, h);
    let raw = resized.into_raw();
    let data = raw
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]].map(|v| v.clamp(0.0, 1.0)))
        .collect();
    let transparency = raw.chunks_exact(4).map(|p| p[3].clamp(0.0, 1.0)).collect();
    Ok(LoadedImage {
        image: RgbImage::new(width, height, data)?,
        transparency,
        source_size: (w0, h0),
        has_alpha,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::{read_split, test_lego_dir, Split};

    #[test]
    fn real_frame_loads_small() {
        let Some(dir) = test_lego_dir() else { return };
        let frames = read_split(&dir, Split::Train).unwrap();
        let path = &frames[0].file_path;
        let black = load_image(path, 32, 32, false).unwrap();
        assert_eq!(
            (black.width, black.height, black.data.len()),
            (32, 32, 32 * 32 * 3)
        );
        assert!(black.data.iter().all(|v| (0.0..=1.0).contains(v)));
        assert_eq!(&black.data[..3], &[0.0, 0.0, 0.0]);
        // The object is there: some pixels are lit.
        assert!(black.data.iter().any(|&v| v > 0.2));
        let white = load_image(path, 32, 32, true).unwrap();
        // Resampling weights sum to 1 only up to f32 rounding.
        assert!(
            white.data[..3].iter().all(|&v| v > 1.0 - 1e-5),
            "{:?}",
            &white.data[..3]
        );
    }

    #[test]
    fn compositing_follows_alpha() {
        let (_dir, path) = nerf_files::test_files::temp_file("a.png");
        // Two pixels: half-transparent red, fully transparent green.
        let rgba: ImageBuffer<image::Rgba<u8>, Vec<u8>> =
            ImageBuffer::from_raw(2, 1, vec![255, 0, 0, 102, 0, 255, 0, 0]).unwrap();
        rgba.save(&path).unwrap();
        let a = 102.0 / 255.0;
        let black = load_image(&path, 2, 1, false).unwrap();
        let expected = [a, 0.0, 0.0, 0.0, 0.0, 0.0];
        for (v, e) in black.data.iter().zip(expected) {
            assert!((v - e).abs() < 1e-6, "{:?}", black.data);
        }
        let white = load_image(&path, 2, 1, true).unwrap();
        let expected = [1.0, 1.0 - a, 1.0 - a, 1.0, 1.0, 1.0];
        for (v, e) in white.data.iter().zip(expected) {
            assert!((v - e).abs() < 1e-6, "{:?}", white.data);
        }
        // Downsizing to one pixel averages the composited colours.
        let one = load_image(&path, 1, 1, false).unwrap();
        assert!((one.data[0] - a / 2.0).abs() < 1e-6, "{:?}", one.data);
        // The transparency carries an image from one background to another, resized or not.
        for (w, h) in [(2, 1), (1, 1)] {
            let (black, t) = load_image_and_transparency(&path, w, h, false).unwrap();
            let white = load_image(&path, w, h, true).unwrap();
            assert_eq!(t.len(), w * h);
            for (i, (b, wh)) in black.data.iter().zip(&white.data).enumerate() {
                assert!((b + t[i / 3] - wh).abs() < 1e-6, "{:?} {t:?}", black.data);
            }
        }
        let (_, t) = load_image_and_transparency(&path, 2, 1, false).unwrap();
        assert!((t[0] - (1.0 - a)).abs() < 1e-6 && (t[1] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn corrupt_or_missing_png_names_the_file() {
        let mut file = tempfile::Builder::new().suffix(".png").tempfile().unwrap();
        std::io::Write::write_all(&mut file, b"\x89PNG\r\n\x1a\n this is not a png").unwrap();
        let err = load_image(file.path(), 8, 8, false)
            .unwrap_err()
            .to_string();
        eprintln!("{err}");
        assert!(err.contains(&file.path().display().to_string()), "{err}");
        assert!(!err.contains('\n'), "{err}");
        let missing = file.path().with_file_name("no_such_image.png");
        let err = load_image(&missing, 8, 8, false).unwrap_err().to_string();
        eprintln!("{err}");
        assert!(err.contains("no_such_image.png"), "{err}");
        let err = load_image(file.path(), 0, 8, false)
            .unwrap_err()
            .to_string();
        eprintln!("{err}");
        assert!(err.contains("size"), "{err}");
    }
}
