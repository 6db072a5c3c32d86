//! How a photo (and its mask) is brought to the size a dataset is loaded at: by a whole
//! factor per side, each output pixel is the plain mean of its block of photo pixels (a box
//! filter, as evaluation protocols downscale held-out photos); by any other ratio, `image`'s
//! `FilterType::Triangle` (bilinear with the kernel widened by the ratio, so that shrinking
//! averages rather than aliases). The same size is kept as it is.

use image::imageops::{self, FilterType};
use image::{ImageBuffer, Pixel};

/// The filter that takes a `from` photo to `to` pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PhotoResize {
    /// The same size: nothing is resampled.
    Unchanged,
    /// Whole factors `(fx, fy)`: the mean of each `fx × fy` block.
    Box(u32, u32),
    /// Any other ratio: the triangle filter.
    Triangle,
}

impl PhotoResize {
    /// The filter from `from = (width, height)` to `to`.
    pub fn between(from: (u32, u32), to: (u32, u32)) -> Self {
        if from == to {
            return PhotoResize::Unchanged;
        }
        let whole = |f: u32, t: u32| (t > 0 && f >= t && f.is_multiple_of(t)).then(|| f / t);
        match (whole(from.0, to.0), whole(from.1, to.1)) {
            (Some(fx), Some(fy)) => PhotoResize::Box(fx, fy),
            _ => PhotoResize::Triangle,
        }
    }

    /// Words for a one-line message: `box-downscaled 1/2`, `box-downscaled 1/1` (the photos'
    /// own size), ….
    pub fn describe(self) -> String {
        match self {
            PhotoResize::Unchanged => "box-downscaled 1/1".to_string(),
            PhotoResize::Box(fx, fy) if fx == fy => format!("box-downscaled 1/{fx}"),
            PhotoResize::Box(fx, fy) => format!("box-downscaled 1/{fx} × 1/{fy}"),
            PhotoResize::Triangle => {
                "resized by the triangle filter (not a whole factor of the photos)".to_string()
            }
        }
    }
}

/// `image` resized to `width × height` by [`PhotoResize::between`] its size and that one.
pub(crate) fn resize_photo<P>(
    image: ImageBuffer<P, Vec<f32>>,
    width: u32,
    height: u32,
) -> ImageBuffer<P, Vec<f32>>
where
    P: Pixel<Subpixel = f32> + 'static,
{
    match PhotoResize::between(image.dimensions(), (width, height)) {
        PhotoResize::Unchanged => image,
        PhotoResize::Box(fx, fy) => box_mean(&image, fx, fy),
        PhotoResize::Triangle => imageops::resize(&image, width, height, FilterType::Triangle),
    }
}

/// The mean of every `fx × fy` block of `image` (whose sides are whole multiples of them).
fn box_mean<P>(image: &ImageBuffer<P, Vec<f32>>, fx: u32, fy: u32) -> ImageBuffer<P, Vec<f32>>
where
    P: Pixel<Subpixel = f32> + 'static,
{
    let channels = P::CHANNEL_COUNT as usize;
    let (w0, h0) = image.dimensions();
    let (w, h) = (w0 / fx, h0 / fy);
    let source = image.as_raw();
    let mut out = vec![0.0f32; w as usize * h as usize * channels];
    let norm = 1.0 / (fx as f64 * fy as f64);
    let mut sums = vec![0.0f64; w as usize * channels];
    for y in 0..h as usize {
        sums.iter_mut().for_each(|s| *s = 0.0);
        for sy in y * fy as usize..(y + 1) * fy as usize {
            let row = &source[sy * w0 as usize * channels..(sy + 1) * w0 as usize * channels];
            for (x, pixel) in row.chunks_exact(channels).enumerate() {
                let target = x / fx as usize * channels;
                for (c, v) in pixel.iter().enumerate() {
                    sums[target + c] += f64::from(*v);
                }
            }
        }
        let dest = &mut out[y * w as usize * channels..(y + 1) * w as usize * channels];
        for (d, s) in dest.iter_mut().zip(&sums) {
            *d = (s * norm) as f32;
        }
    }
    ImageBuffer::from_raw(w, h, out).expect("a buffer of the block means' size")
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{Luma, Rgba};

    #[test]
    fn whole_factors_take_the_block_mean_and_other_ratios_the_triangle_filter() {
        assert_eq!(PhotoResize::between((8, 4), (8, 4)), PhotoResize::Unchanged);
        assert_eq!(PhotoResize::between((8, 4), (4, 2)), PhotoResize::Box(2, 2));
        assert_eq!(PhotoResize::between((9, 4), (3, 4)), PhotoResize::Box(3, 1));
        assert_eq!(PhotoResize::between((8, 4), (3, 2)), PhotoResize::Triangle);
        assert_eq!(PhotoResize::between((4, 4), (8, 8)), PhotoResize::Triangle);
        assert_eq!(PhotoResize::Box(2, 2).describe(), "box-downscaled 1/2");
        // 4×2 grey: each 2×2 block's mean.
        let grey: ImageBuffer<Luma<f32>, Vec<f32>> =
            ImageBuffer::from_raw(4, 2, vec![0.0, 1.0, 0.5, 0.5, 1.0, 0.0, 0.25, 0.75]).unwrap();
        let half = resize_photo(grey, 2, 1);
        assert_eq!(half.as_raw(), &vec![0.5, 0.5]);
        // Channels stay apart.
        let rgba: ImageBuffer<Rgba<f32>, Vec<f32>> = ImageBuffer::from_fn(2, 2, |x, y| {
            Rgba([x as f32, y as f32, 1.0, (x + y) as f32 / 2.0])
        });
        let one = resize_photo(rgba, 1, 1);
        assert_eq!(one.as_raw(), &vec![0.5, 0.5, 1.0, 0.5]);
    }
}
