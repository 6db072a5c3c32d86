//! Wall-clock timing for `nerf bench` and `nerf report`: each run of a piece of work timed,
//! and the best-of-N figure the tables print.

use std::time::Instant;

use anyhow::Result;

/// Runs `work` `repeats` times (at least once); returns each run's wall time in seconds and
/// the last run's result. The best-of-N figure is [`fastest`] of the times.
pub(crate) fn time_runs<T>(
    repeats: usize,
    mut work: impl FnMut() -> Result<T>,
) -> Result<(Vec<f64>, T)> {
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
pub(crate) fn fastest(runs: &[f64]) -> f64 {
    runs.iter().copied().fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;

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
        // The two long runs cannot be the shortest unless the short one took longer.
        assert!(fastest(&runs) < 0.2, "{runs:?}");
    }
}
