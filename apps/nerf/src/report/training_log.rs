//! Training logs (`.log.jsonl`) read into PSNR curves against wall-clock time.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use serde::Serialize;

/// Test PSNR and per-epoch training PSNR of one training log against its wall clock.
#[derive(Debug, Clone, Serialize)]
pub struct TrainingCurve {
    /// The training log read.
    pub log: PathBuf,
    /// `(wall seconds, epoch, test PSNR)` at each evaluation.
    pub test: Vec<(f64, usize, f64)>,
    /// Test views of each evaluation.
    pub test_views: Option<usize>,
    /// `(wall seconds at the epoch's last step, epoch, mean training-batch PSNR)`.
    pub train: Vec<(f64, usize, f64)>,
}

/// The largest training log a report reads (a 45-minute run logs about 2 MB).
const MAX_LOG_BYTES: u64 = 256 << 20;

/// Reads a training log (`.log.jsonl`, one JSON object per line: steps with `psnr`,
/// evaluations with `test_psnr`).
pub fn read_training_log(path: &Path) -> Result<TrainingCurve> {
    // A regular file of bounded size: a FIFO or /dev/zero given as --log is refused, not read
    // forever.
    let bytes = nerf::io::bounded_read::read_regular_file(path, "training log", MAX_LOG_BYTES)?;
    let text = String::from_utf8(bytes)
        .map_err(|_| anyhow::anyhow!("training log {} is not UTF-8 text", path.display()))?;
    let mut test = Vec::new();
    let mut test_views = None;
    // epoch -> (last wall_s, psnr sum, count)
    let mut epochs: std::collections::BTreeMap<usize, (f64, f64, usize)> = Default::default();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v: serde_json::Value = serde_json::from_str(line)
            .with_context(|| format!("{} line {}: not JSON", path.display(), i + 1))?;
        let num = |k: &str| v.get(k).and_then(|x| x.as_f64());
        let (Some(wall), Some(epoch)) = (num("wall_s"), num("epoch")) else {
            bail!("{} line {}: no wall_s or epoch", path.display(), i + 1);
        };
        if let Some(p) = num("test_psnr") {
            test.push((wall, epoch as usize, p));
            test_views = num("test_views").map(|n| n as usize).or(test_views);
        } else if let Some(p) = num("psnr") {
            let e = epochs.entry(epoch as usize).or_insert((0.0, 0.0, 0));
            *e = (e.0.max(wall), e.1 + p, e.2 + 1);
        }
    }
    let train: Vec<_> = epochs
        .into_iter()
        .map(|(epoch, (wall, sum, n))| (wall, epoch, sum / n as f64))
        .collect();
    if train.is_empty() && test.is_empty() {
        bail!("{}: no training steps logged", path.display());
    }
    Ok(TrainingCurve {
        log: path.to_path_buf(),
        test,
        test_views,
        train,
    })
}

/// Wall-clock minutes at which a curve first reaches each PSNR.
pub(super) fn minutes_to_reach(points: &[(f64, usize, f64)], target: f64) -> Option<(f64, usize)> {
    points
        .iter()
        .find(|(_, _, p)| *p >= target)
        .map(|(w, e, _)| (w / 60.0, *e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_training_log_that_is_no_regular_file_is_refused_without_reading() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("run.log.jsonl");
        let path = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: `path` is a NUL-terminated string that outlives the call.
        assert_eq!(unsafe { libc::mkfifo(path.as_ptr(), 0o600) }, 0);
        let err = format!("{:#}", read_training_log(&fifo).unwrap_err());
        assert!(
            err.contains("FIFO") && err.contains("training log"),
            "{err}"
        );
        let err = format!(
            "{:#}",
            read_training_log(Path::new("/dev/zero")).unwrap_err()
        );
        assert!(err.contains("device"), "{err}");
    }

    #[test]
    fn training_log_groups_steps_by_epoch_and_keeps_evaluations() {
        let dir = std::env::temp_dir().join(format!("nerf-report-log-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("x.log.jsonl");
        std::fs::write(
            &path,
            concat!(
                "{\"step\":1,\"epoch\":0,\"wall_s\":1.0,\"loss\":0.1,\"psnr\":10.0}\n",
                "{\"step\":2,\"epoch\":0,\"wall_s\":2.0,\"loss\":0.1,\"psnr\":12.0}\n",
                "{\"step\":2,\"epoch\":1,\"wall_s\":2.5,\"test_psnr\":15.5,\"test_views\":20}\n",
                "\n",
                "{\"step\":3,\"epoch\":1,\"wall_s\":3.0,\"loss\":0.1,\"psnr\":14.0}\n",
            ),
        )
        .unwrap();
        let c = read_training_log(&path).unwrap();
        assert_eq!(c.train, vec![(2.0, 0, 11.0), (3.0, 1, 14.0)]);
        assert_eq!(c.test, vec![(2.5, 1, 15.5)]);
        assert_eq!(c.test_views, Some(20));
        assert_eq!(minutes_to_reach(&c.test, 15.0), Some((2.5 / 60.0, 1)));
        assert_eq!(minutes_to_reach(&c.test, 16.0), None);
        std::fs::write(&path, "{\"step\":1}\nnot json\n").unwrap();
        let err = read_training_log(&path).unwrap_err().to_string();
        assert!(err.contains("line 1"), "{err}");
        // An empty log is an error (the report notes it and leaves the plot out).
        std::fs::write(&path, "\n").unwrap();
        let err = read_training_log(&path).unwrap_err().to_string();
        assert!(err.contains("no training steps"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
