//! Image metrics and small statistics, written once: PSNR, mean, best-of-N timing.

use std::time::Instant;

use anyhow::Result;

use crate::core::image::RgbImage;

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

/// Runs `work` `repeats` times (at least once); returns each run's wall time in seconds and
/// the last run's result. The best-of-N figure is [`fastest`] of the times.
pub fn time_runs<T>(repeats: usize, mut work: impl FnMut() -> Result<T>) -> Result<(Vec<f64>, T)> {
    let mut runs = Vec::with_capacity(repeats.max(1));
    let mut last = None;
    for _ in 0..repeats.max(1) {
        let start = Instant::now();
        last = Some(work()?);
        runs.push(start.elapsed().as_secs_f64());
    }
    Ok((runs, last.expect("at least one run")))
}

/// The shortest of `runs` (∞ when empty).
pub fn fastest(runs: &[f64]) -> f64 {
    runs.iter().copied().fold(f64::INFINITY, f64::min)
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
        assert!((mean_psnr(&[&a], &[b]) - 20.0).abs() < 1e-6);
        assert_eq!(mean(&[]), 0.0);
    }

    #[test]
    fn time_runs_times_every_run() {
        let mut n = 0;
        let (runs, last) = time_runs(3, || {
            n += 1;
            std::thread::sleep(std::time::Duration::from_millis(if n == 2 {
                1
            } else {
                200
            }));
            Ok(n)
        })
        .unwrap();
        assert_eq!(last, 3);
        assert_eq!(runs.len(), 3);
        assert!(runs[0] >= 0.2 && runs[2] >= 0.2);
        // The 200 ms runs cannot be the shortest unless the 1 ms run took longer.
        assert!(fastest(&runs) < 0.2, "{runs:?}");
    }
}
