//! Image metrics and small statistics, written once: PSNR, SSIM, mean, best-of-N timing.

use anyhow::{bail, Result};

use crate::image::RgbImage;

/// PSNR in dB of a mean squared error of colours in [0, 1]: `−10·log10(mse)` (∞ at 0).
pub fn psnr_from_mse(mse: f64) -> f64 {
    if mse == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}

/// PSNR in dB between two colour images in [0, 1].
pub fn psnr(a: &RgbImage, b: &RgbImage) -> f64 {
    let mse = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        / a.data.len() as f64;
    psnr_from_mse(mse)
}

/// PSNR in dB between two colour images in [0, 1] over the pixels whose `used` flag
/// (row-major, one per pixel) is set: the mean squared error of those pixels' channels only.
pub fn psnr_over(a: &RgbImage, b: &RgbImage, used: &[bool]) -> f64 {
    let (sum, n) = a
        .data
        .chunks_exact(3)
        .zip(b.data.chunks_exact(3))
        .zip(used)
        .filter(|(_, &u)| u)
        .fold((0.0f64, 0usize), |(sum, n), ((x, y), _)| {
            let e: f64 = x.iter().zip(y).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
            (sum + e, n + 3)
        });
    psnr_from_mse(sum / n.max(1) as f64)
}

/// Side of SSIM's Gaussian window (11, as the SSIM paper and scikit-image with σ 1.5).
pub const SSIM_WINDOW: usize = 11;

/// SSIM's Gaussian window weights: `exp(−x²/(2·1.5²))` for x in −5..=5, normalised to sum 1
/// (scipy's `gaussian_filter` with σ 1.5 and truncate 3.5, which scikit-image uses).
fn ssim_weights() -> [f64; SSIM_WINDOW] {
    let sigma = 1.5f64;
    let half = (SSIM_WINDOW / 2) as f64;
    let mut w = [0.0; SSIM_WINDOW];
    for (i, v) in w.iter_mut().enumerate() {
        let x = i as f64 - half;
        *v = (-0.5 * x * x / (sigma * sigma)).exp();
    }
    let sum: f64 = w.iter().sum();
    w.map(|v| v / sum)
}

/// Gaussian-weighted mean of `plane` (`height · width` row-major) over every full 11×11 window:
/// the `(height − 10) · (width − 10)` valid positions, row-major (separable: rows, then columns).
fn window_means(plane: &[f64], width: usize, height: usize, w: &[f64; SSIM_WINDOW]) -> Vec<f64> {
    let (ow, oh) = (width + 1 - SSIM_WINDOW, height + 1 - SSIM_WINDOW);
    let mut rows = vec![0.0; height * ow];
    for y in 0..height {
        for x in 0..ow {
            rows[y * ow + x] = (0..SSIM_WINDOW)
                .map(|k| w[k] * plane[y * width + x + k])
                .sum();
        }
    }
    let mut out = vec![0.0; oh * ow];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..SSIM_WINDOW)
                .map(|k| w[k] * rows[(y + k) * ow + x])
                .sum();
        }
    }
    out
}

/// Mean SSIM of one channel pair (`height · width` planes, values in [0, 1]) over the valid
/// windows: `(2·μx·μy + C1)(2·σxy + C2) / ((μx² + μy² + C1)(σx² + σy² + C2))`, C1 = 0.01²,
/// C2 = 0.03², with population (not sample) variances.
fn ssim_plane(a: &[f64], b: &[f64], width: usize, height: usize) -> f64 {
    let w = ssim_weights();
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let prod = |p: &[f64], q: &[f64]| p.iter().zip(q).map(|(x, y)| x * y).collect::<Vec<_>>();
    let mu_a = window_means(a, width, height, &w);
    let mu_b = window_means(b, width, height, &w);
    let aa = window_means(&prod(a, a), width, height, &w);
    let bb = window_means(&prod(b, b), width, height, &w);
    let ab = window_means(&prod(a, b), width, height, &w);
    let n = mu_a.len();
    let total: f64 = (0..n)
        .map(|i| {
            let (ma, mb) = (mu_a[i], mu_b[i]);
            let (va, vb, vab) = (aa[i] - ma * ma, bb[i] - mb * mb, ab[i] - ma * mb);
            ((2.0 * ma * mb + c1) * (2.0 * vab + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
        })
        .sum();
    total / n as f64
}

/// SSIM between two colour images in [0, 1] (data range 1): per channel with an 11×11
/// Gaussian window (σ 1.5), K1 0.01, K2 0.03, averaged over the windows that lie fully inside
/// the image (scikit-image crops the 5-pixel border the same way), then over the 3 channels.
/// Equals scikit-image's `structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
/// use_sample_covariance=False, data_range=1, channel_axis=-1)`. An error when the sizes
/// differ or a side is under 11 pixels.
pub fn ssim(a: &RgbImage, b: &RgbImage) -> Result<f64> {
    if (a.width, a.height) != (b.width, b.height) {
        bail!(
            "SSIM of images of different sizes: {}x{} and {}x{}",
            a.width,
            a.height,
            b.width,
            b.height
        );
    }
    if a.width < SSIM_WINDOW || a.height < SSIM_WINDOW {
        bail!(
            "SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {}x{}",
            a.width,
            a.height
        );
    }
    let channel = |img: &RgbImage, c: usize| -> Vec<f64> {
        img.data
            .iter()
            .skip(c)
            .step_by(3)
            .map(|&v| v as f64)
            .collect()
    };
    let sum: f64 = (0..3)
        .map(|c| ssim_plane(&channel(a, c), &channel(b, c), a.width, a.height))
        .sum();
    Ok(sum / 3.0)
}

/// Mean of `values` (0 when empty).
pub fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len().max(1) as f64
}

/// Mean PSNR of each predicted image against its ground truth, pairwise.
pub fn mean_psnr(predicted: &[&RgbImage], truth: &[RgbImage]) -> f64 {
    mean(
        &predicted
            .iter()
            .zip(truth)
            .map(|(p, t)| psnr(p, t))
            .collect::<Vec<_>>(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_of_known_errors() {
        assert_eq!(psnr_from_mse(0.01), 20.0);
        assert!(psnr_from_mse(0.0).is_infinite());
        let a = RgbImage::new(1, 1, vec![0.0, 0.0, 0.0]).unwrap();
        let b = RgbImage::new(1, 1, vec![0.1, 0.1, 0.1]).unwrap();
        assert!((psnr(&a, &b) - 20.0).abs() < 1e-6);
        assert!((mean_psnr(&[&a], std::slice::from_ref(&b)) - 20.0).abs() < 1e-6);
        // Over the used pixels only: the second pixel's error is left out.
        let a2 = RgbImage::new(2, 1, vec![0.0; 6]).unwrap();
        let b2 = RgbImage::new(2, 1, vec![0.1, 0.1, 0.1, 0.9, 0.9, 0.9]).unwrap();
        assert!((psnr_over(&a2, &b2, &[true, false]) - 20.0).abs() < 1e-6);
        assert!((psnr_over(&a2, &b2, &[true, true]) - psnr(&a2, &b2)).abs() < 1e-12);
        assert_eq!(mean(&[]), 0.0);
    }

    #[test]
    fn ssim_agrees_with_scikit_image() {
        // tests/fixtures/ssim.json is written by scripts/make_ssim_fixture.py with skimage.
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../tests/fixtures/ssim.json"
        );
        let fixture: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let (w, h) = (
            fixture["width"].as_u64().unwrap() as usize,
            fixture["height"].as_u64().unwrap() as usize,
        );
        let image = |key: &str| {
            let data = fixture[key].as_array().unwrap();
            RgbImage::new(
                w,
                h,
                data.iter().map(|v| v.as_f64().unwrap() as f32).collect(),
            )
            .unwrap()
        };
        let expected = fixture["ssim"].as_f64().unwrap();
        let got = ssim(&image("a"), &image("b")).unwrap();
        assert!(
            (got - expected).abs() < 1e-9,
            "{got} against skimage's {expected}"
        );
        assert!(expected < 0.9, "the fixture's images should differ clearly");
    }

    #[test]
    fn ssim_of_identical_images_is_one_and_sizes_are_checked() {
        let data: Vec<f32> = (0..12 * 13 * 3)
            .map(|i| ((i * 37) % 101) as f32 / 100.0)
            .collect();
        let a = RgbImage::new(12, 13, data).unwrap();
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
        let small = RgbImage::new(10, 13, vec![0.0; 10 * 13 * 3]).unwrap();
        assert!(ssim(&small, &small).is_err());
        assert!(ssim(&a, &small).is_err());
        let w = ssim_weights();
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12 && w[5] > w[4] && w[0] == w[10]);
    }
}
