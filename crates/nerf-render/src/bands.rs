//! Images worked through in bands of pixels, so that what is held at once does not grow with
//! the image: the rays of a band are made from the homework's pixel grid (see
//! [`nerf_core::rays`]) exactly as [`Rays::for_image`] makes them for the whole image, so a
//! per-pixel result does not depend on the band size.

use std::ops::Range;

use anyhow::Result;
use candle_core::Device;

use nerf_core::camera::Camera;
use nerf_core::rays::{linspace, Rays};

/// Rays per band of an image by default (rounded to whole renderer chunks where rendered):
/// 2^18 rays are about 60 MB of rays, pixels and outputs, on top of the renderer's chunk.
pub const BAND_RAYS: usize = 1 << 18;

/// The row-major pixel ranges `0..n` in bands of `band` pixels (at least 1), the last one
/// shorter.
pub fn pixel_bands(n: usize, band: usize) -> impl Iterator<Item = Range<usize>> {
    let band = band.max(1);
    (0..n)
        .step_by(band)
        .map(move |start| start..(start + band).min(n))
}

/// The NDC points `(x, y)` of pixels `pixels` (row-major indices) of a `width × height` image:
/// the values [`nerf_core::rays::pixel_grid_values`] gives those pixels.
pub fn band_ndc(width: usize, height: usize, pixels: Range<usize>) -> Vec<[f64; 2]> {
    let (xs, ys) = (linspace(-1.0, 1.0, width), linspace(-1.0, 1.0, height));
    pixels.map(|i| [-xs[i % width], -ys[i / width]]).collect()
}

/// The rays of pixels `pixels` (row-major indices) of `camera`'s `width × height` image: rows
/// `pixels` of [`Rays::for_image`], bit for bit.
pub fn band_rays(
    camera: &Camera,
    (width, height): (usize, usize),
    pixels: Range<usize>,
    device: &Device,
) -> Result<Rays> {
    Rays::for_pixel_range(camera, (width, height), pixels, device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use nerf_core::camera::surround_cameras;
    use nerf_core::rays::pixel_grid_values;

    #[test]
    fn bands_cover_the_image_once_and_make_its_rays() {
        let (w, h) = (7, 5);
        for band in [1, 3, 35, 36, 1000] {
            let bands: Vec<_> = pixel_bands(w * h, band).collect();
            let covered: Vec<usize> = bands.iter().flat_map(|r| r.clone()).collect();
            assert_eq!(covered, (0..w * h).collect::<Vec<_>>(), "band {band}");
            assert!(bands.iter().all(|r| r.len() <= band));
        }
        assert_eq!(band_ndc(w, h, 0..w * h), pixel_grid_values(w, h));
        let camera = surround_cameras(3.0, 1, DVec3::Y, 1.0)[0];
        let whole =
            Rays::for_image(&nerf_core::camera::Camera::from(camera), w, h, &Device::Cpu).unwrap();
        let part = band_rays(
            &nerf_core::camera::Camera::from(camera),
            (w, h),
            9..23,
            &Device::Cpu,
        )
        .unwrap();
        let rows = |t: &candle_core::Tensor| t.to_vec2::<f32>().unwrap();
        assert_eq!(
            rows(&part.directions),
            rows(&whole.directions.narrow(0, 9, 14).unwrap())
        );
        assert_eq!(
            rows(&part.origins),
            rows(&whole.origins.narrow(0, 9, 14).unwrap())
        );
    }
}
