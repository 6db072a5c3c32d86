//! The pace of a training run: the learning rate of a run that follows its time budget, and
//! the rays of a step that should evaluate a set number of samples.

/// The learning rate after `progress` (0 to 1, clamped) of a run that follows its time budget:
/// `lr · gamma^progress`, from `lr` at the start to `lr · gamma` at the end.
pub(crate) fn time_learning_rate(lr: f64, gamma: f64, progress: f64) -> f64 {
    lr * gamma.powf(progress.clamp(0.0, 1.0))
}

/// The rays of the next step when each step should evaluate about `target` samples and the
/// last one evaluated `evaluated` with `rays` rays: the geometric mean of `rays` and the count
/// that would have hit the target (damped, so the count settles), within 64..=`max_rays`.
pub fn next_rays(rays: usize, evaluated: usize, target: usize, max_rays: usize) -> usize {
    let ideal = rays as f64 * target as f64 / evaluated.max(1) as f64;
    ((rays as f64 * ideal).sqrt().round() as usize).clamp(64, max_rays.max(64))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_learning_rate_falls_from_lr_to_lr_gamma_over_the_budget() {
        let lr = |p: f64| time_learning_rate(0.01, 0.1, p);
        assert_eq!(lr(0.0), 0.01);
        assert!((lr(1.0) - 0.001).abs() < 1e-15);
        assert!((lr(0.5) - 0.01 * 0.1f64.sqrt()).abs() < 1e-15);
        // Before the start and past the end it holds its ends.
        assert_eq!(lr(-3.0), 0.01);
        assert!((lr(7.0) - 0.001).abs() < 1e-15);
        let steps: Vec<f64> = (0..=10).map(|k| lr(k as f64 / 10.0)).collect();
        assert!(steps.windows(2).all(|w| w[1] < w[0]));
    }

    #[test]
    fn rays_settle_where_the_samples_meet_the_target() {
        // A scene where each ray evaluates 4 samples: 16384 samples need 4096 rays.
        let mut rays = 1024;
        for _ in 0..40 {
            rays = next_rays(rays, 4 * rays, 16384, 1 << 16);
        }
        assert!((4090..=4100).contains(&rays), "{rays}");
        // Bounds: no sample evaluated asks for the most; too many for the fewest.
        assert_eq!(next_rays(1000, 0, 16384, 5000), 5000);
        assert_eq!(next_rays(100, 1 << 30, 16, 5000), 64);
    }
}
