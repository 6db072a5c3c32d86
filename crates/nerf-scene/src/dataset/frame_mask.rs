//! A frame's mask: a PNG of the photo's own size in which 0 marks a pixel to ignore (a moving
//! person, the photographer's shadow, a region with no valid colour) and any other value one
//! to use, as nerfstudio reads `mask_path`. Training draws no ray from an ignored pixel and
//! evaluation scores only the used ones.
//!
//! **The rule, for every kind of PNG** ([`pixel_is_used`]): a pixel is used when any of its
//! colour channels is non-zero at the file's own bit depth, and ignored when all are 0. So 8-
//! and 16-bit grey is used where the value is not 0 (a 16-bit 1 counts, it is not rounded to 8
//! bits first), RGB where any of red, green or blue is not 0 (`(0, 0, 1)` is used), a palette
//! image by the colour its index names (an index whose colour is black is ignored, whatever
//! the index), and an alpha channel is never read (a transparent white pixel is used).

use std::path::Path;

use anyhow::{anyhow, bail, Result};
use image::{DynamicImage, ImageBuffer, ImageFormat, Luma};

use super::dataset_error::read_dataset_file;
use super::frame_image::{MAX_IMAGE_FILE_BYTES, MAX_SOURCE_IMAGE_SIDE};
use nerf_files::decode_budget::{file_decode_cost, reserve};

/// Which pixels of a `width × height` image are used, as flags and as a list.
#[derive(Debug, Clone, PartialEq)]
pub struct PixelMask {
    /// `width × height` flags, row-major: true for a used pixel.
    used: Vec<bool>,
    /// The indices of the used pixels, ascending (what training draws from).
    used_pixels: Vec<u32>,
}

impl PixelMask {
    /// The mask of `used` flags (row-major pixels).
    pub fn from_flags(used: Vec<bool>) -> Self {
        let used_pixels = (0..used.len() as u32)
            .filter(|&p| used[p as usize])
            .collect();
        Self { used, used_pixels }
    }

    /// Row-major flags, true for a used pixel.
    pub fn used(&self) -> &[bool] {
        &self.used
    }

    /// The used pixels' indices, ascending.
    pub fn used_pixels(&self) -> &[u32] {
        &self.used_pixels
    }
}

/// The mask at `path` for `image` (whose file is `source_size` pixels), resized to `width ×
/// height`: a pixel of the resized image is used only when no ignored pixel of the photo
/// enters its colour (the flags as 0 and 1, resized with the filter the images use, must stay
/// 1), so that what an ignored region holds never reaches training or the score. One-line errors
/// name the file: unreadable, not a PNG, not the image's size, or ignoring every pixel.
pub(crate) fn load_mask(
    path: &Path,
    image: &Path,
    source_size: (u32, u32),
    (width, height): (usize, usize),
) -> Result<PixelMask> {
    // Within the decoding budget, as the photos are (`nerf_files::decode_budget`).
    let _reservation = reserve(file_decode_cost(path));
    let bytes = read_dataset_file(path, "mask", MAX_IMAGE_FILE_BYTES)?;
    if image::guess_format(&bytes).ok() != Some(ImageFormat::Png) {
        bail!("mask {} is not a PNG image", path.display());
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_SOURCE_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_SOURCE_IMAGE_SIDE);
    let mut reader =
        image::ImageReader::with_format(std::io::Cursor::new(&bytes), ImageFormat::Png);
    reader.limits(limits);
    let decoded = reader.decode().map_err(|e| {
        anyhow!(
            "cannot decode mask {}: {}",
            path.display(),
            e.to_string().replace('\n', " ")
        )
    })?;
    let (w0, h0) = (decoded.width(), decoded.height());
    if (w0, h0) != source_size {
        bail!(
            "mask {} is {w0}x{h0}, but its image {} is {}x{}: a mask must have its image's size",
            path.display(),
            image.display(),
            source_size.0,
            source_size.1
        );
    }
    // (H0, W0): 1 for a used pixel, 0 for an ignored one.
    let flags = used_flags(&decoded);
    let (w, h) = (width as u32, height as u32);
    let used: Vec<bool> = if (w0, h0) == (w, h) {
        flags.iter().map(|&f| f > 0.5).collect()
    } else {
        let buffer: ImageBuffer<Luma<f32>, Vec<f32>> = ImageBuffer::from_raw(w0, h0, flags)
            .ok_or_else(|| anyhow!("cannot decode mask {}: inconsistent size", path.display()))?;
        super::photo_resize::resize_photo(buffer, w, h)
            .into_raw()
            .into_iter()
            .map(|f| f >= 1.0 - 1e-5)
            .collect()
    };
    let mask = PixelMask::from_flags(used);
    if mask.used_pixels.is_empty() {
        bail!(
            "mask {} ignores every pixel of {} at {width}x{height}: that image gives no rays \
             (remove it, or its mask)",
            path.display(),
            image.display()
        );
    }
    Ok(mask)
}

/// The line that says how many of a split's `frames` (of the dataset in `dir`) have masks
/// and where they are: `masks: 66 of 66 frames of the train split from masks/ (pixels where
/// a mask is 0 are neither trained on nor scored)`.
pub(crate) fn masks_line(dir: &Path, split: super::Split, frames: &[super::Frame]) -> String {
    let masked: Vec<&Path> = frames
        .iter()
        .filter_map(|f| f.mask_path.as_deref())
        .collect();
    let mut folders: Vec<String> = masked
        .iter()
        .map(|m| {
            let relative = m.strip_prefix(dir).unwrap_or(m);
            let mut parts = relative.components();
            match (parts.next(), parts.next()) {
                (Some(first), Some(_)) => format!("{}/", first.as_os_str().to_string_lossy()),
                _ => "the capture's folder".to_string(),
            }
        })
        .collect();
    folders.sort();
    folders.dedup();
    let shown = folders.len().min(3);
    let more = if folders.len() > shown { ", …" } else { "" };
    format!(
        "masks: {} of {} frames of the {split} split from {}{more} (pixels where a mask is 0 \
         are neither trained on nor scored)",
        masked.len(),
        frames.len(),
        folders[..shown].join(", ")
    )
}

/// Whether a mask pixel is used: any of its colour channels non-zero. `pixel` is the pixel's
/// bytes as decoded (native-endian samples of `bytes_per_sample` bytes), `colour_samples` how
/// many of its leading samples are colour (the alpha sample after them is not read).
pub(crate) fn pixel_is_used(pixel: &[u8], colour_samples: usize, bytes_per_sample: usize) -> bool {
    pixel[..colour_samples * bytes_per_sample]
        .iter()
        .any(|&b| b != 0)
}

/// Row-major flags of a decoded mask, 1 for a used pixel ([`pixel_is_used`]), read from the
/// decoded bytes as they are (no conversion, which would round a 16-bit 1 or an RGB
/// `(0, 0, 1)` to a grey 0).
fn used_flags(decoded: &DynamicImage) -> Vec<f32> {
    let colour = decoded.color();
    let samples = usize::from(colour.channel_count());
    let bytes_per_sample = usize::from(colour.bytes_per_pixel()) / samples;
    let colour_samples = samples - usize::from(colour.has_alpha());
    decoded
        .as_bytes()
        .chunks_exact(samples * bytes_per_sample)
        .map(|pixel| {
            if pixel_is_used(pixel, colour_samples, bytes_per_sample) {
                1.0
            } else {
                0.0
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_mask(path: &Path, w: u32, h: u32, value: impl Fn(u32, u32) -> u8) {
        image::GrayImage::from_fn(w, h, |x, y| Luma([value(x, y)]))
            .save(path)
            .unwrap();
    }

    #[test]
    fn zero_is_ignored_and_a_resized_pixel_touched_by_an_ignored_one_is_ignored() {
        let (_dir, path) = nerf_files::test_files::temp_file("m.png");
        // The left quarter ignored, the rest used (any non-zero value).
        write_mask(&path, 8, 4, |x, _| if x < 2 { 0 } else { 7 });
        let image = Path::new("a.jpg");
        let full = load_mask(&path, image, (8, 4), (8, 4)).unwrap();
        assert_eq!(full.used_pixels().len(), 24);
        assert!(!full.used()[1] && full.used()[2] && !full.used()[9]);
        let half = load_mask(&path, image, (8, 4), (4, 2)).unwrap();
        // At half size each pixel is the mean of a 2×2 block (the images' box filter):
        // column 0 holds ignored source columns 0 and 1, column 1 only used ones.
        assert_eq!(
            half.used(),
            &[false, true, true, true, false, true, true, true]
        );
        assert_eq!(half.used_pixels(), &[1, 2, 3, 5, 6, 7]);
        // By another ratio the triangle filter's wider support reaches the ignored columns.
        let third = load_mask(&path, image, (8, 4), (3, 2)).unwrap();
        assert!(!third.used()[0] && third.used()[2], "{:?}", third.used());
    }

    #[test]
    fn a_mask_of_another_size_or_all_zero_is_an_error_naming_it() {
        let (dir, path) = nerf_files::test_files::temp_file("m.png");
        write_mask(&path, 8, 4, |_, _| 255);
        let err = load_mask(&path, Path::new("a.jpg"), (8, 5), (8, 5))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("m.png is 8x4") && err.contains("a.jpg is 8x5") && !err.contains('\n'),
            "{err}"
        );
        write_mask(&path, 8, 4, |_, _| 0);
        let err = load_mask(&path, Path::new("a.jpg"), (8, 4), (8, 4))
            .unwrap_err()
            .to_string();
        assert!(err.contains("ignores every pixel"), "{err}");
        std::fs::write(&path, b"not a png").unwrap();
        let err = load_mask(&path, Path::new("a.jpg"), (8, 4), (8, 4)).unwrap_err();
        assert!(err.to_string().contains("not a PNG"), "{err}");
        let missing = dir.path().join("none.png");
        let err = load_mask(&missing, Path::new("a.jpg"), (8, 4), (8, 4)).unwrap_err();
        assert!(err.to_string().contains("none.png"), "{err}");
    }

    /// The mask of `m.png` written as `image`, at its own size: the used flags.
    fn flags_of(image: DynamicImage) -> Vec<bool> {
        let (_dir, path) = nerf_files::test_files::temp_file("m.png");
        image.save(&path).unwrap();
        let (w, h) = (image.width(), image.height());
        let mask = load_mask(&path, Path::new("a.jpg"), (w, h), (w as usize, h as usize));
        mask.unwrap().used().to_vec()
    }

    #[test]
    fn every_kind_of_png_follows_one_rule_any_colour_channel_non_zero() {
        use image::{ImageBuffer, LumaA, Rgb, Rgba};
        // 8-bit grey: 0 ignored, 1 and 100 used.
        let grey = image::GrayImage::from_fn(3, 1, |x, _| Luma([[0, 1, 100][x as usize]]));
        assert_eq!(flags_of(grey.into()), [false, true, true]);
        // 16-bit grey: a 1 and a band of 100 are used (not rounded to 8 bits).
        let grey16: ImageBuffer<Luma<u16>, Vec<u16>> =
            ImageBuffer::from_fn(3, 1, |x, _| Luma([[0, 1, 100][x as usize]]));
        assert_eq!(
            flags_of(DynamicImage::ImageLuma16(grey16)),
            [false, true, true]
        );
        // Grey with alpha: the alpha is not read.
        let grey_alpha: ImageBuffer<LumaA<u8>, Vec<u8>> =
            ImageBuffer::from_fn(2, 1, |x, _| LumaA([[0, 255][x as usize], 0]));
        assert_eq!(
            flags_of(DynamicImage::ImageLumaA8(grey_alpha)),
            [false, true]
        );
        // RGB: any channel; (0, 0, 1) is used.
        let rgb = image::RgbImage::from_fn(3, 1, |x, _| {
            Rgb([[0, 0, 0], [0, 0, 1], [200, 0, 0]][x as usize])
        });
        assert_eq!(flags_of(rgb.into()), [false, true, true]);
        // 16-bit RGBA: colour decides, alpha not read.
        let rgba16: ImageBuffer<Rgba<u16>, Vec<u16>> = ImageBuffer::from_fn(3, 1, |x, _| {
            Rgba([[0, 0, 0, 65535], [0, 1, 0, 0], [0, 0, 0, 0]][x as usize])
        });
        assert_eq!(
            flags_of(DynamicImage::ImageRgba16(rgba16)),
            [false, true, false]
        );
    }

    #[test]
    fn a_palette_mask_is_read_by_the_colour_its_index_names() {
        // Index 0 names white and index 1 black: the black one is ignored, whatever its index.
        let (_dir, path) = nerf_files::test_files::temp_file("m.png");
        {
            let file = std::fs::File::create(&path).unwrap();
            let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), 4, 1);
            encoder.set_color(png::ColorType::Indexed);
            encoder.set_depth(png::BitDepth::Eight);
            encoder.set_palette(vec![255, 255, 255, 0, 0, 0]);
            let mut writer = encoder.write_header().unwrap();
            writer.write_image_data(&[0, 1, 1, 0]).unwrap();
        }
        let mask = load_mask(&path, Path::new("a.jpg"), (4, 1), (4, 1)).unwrap();
        assert_eq!(mask.used(), &[true, false, false, true]);
    }
}
