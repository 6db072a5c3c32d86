//! Running COLMAP's command line: finding the executable (`colmap` on `PATH`, or the one
//! `NERF_COLMAP` names), checking that it runs, and running one stage with its output written
//! to a log while a progress bar follows what the stage prints.

use crate::process::external_tool::ExternalTool;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{anyhow, Context, Result};

use nerf::io::progress::progress_bar;

/// The environment variable naming the COLMAP executable (default: `colmap` on `PATH`).
pub const COLMAP_ENV: &str = "NERF_COLMAP";

/// The COLMAP executable: `$NERF_COLMAP` when set, else `colmap` (looked up on `PATH`).
pub fn colmap_program() -> PathBuf {
    std::env::var_os(COLMAP_ENV)
        .filter(|v| !v.is_empty())
        .map_or_else(|| PathBuf::from("colmap"), PathBuf::from)
}

/// A COLMAP command with its environment: no display (`QT_QPA_PLATFORM=offscreen`), no input.
fn colmap_command(program: &Path, stage: &str) -> Command {
    let mut command = Command::new(program);
    command
        .arg(stage)
        .env("QT_QPA_PLATFORM", "offscreen")
        .stdin(Stdio::null());
    command
}

/// Checks that `program` runs (`colmap help`); the one-line error says that COLMAP is
/// missing and how to install it.
pub fn check_colmap(program: &Path) -> Result<()> {
    let colmap = ExternalTool {
        name: "COLMAP",
        env: COLMAP_ENV,
        package: "colmap",
    };
    colmap.check(colmap_command(program, "help"), program)
}

/// Progress a line of COLMAP's output reports: `(done, of)` steps, where `of` is `None` when
/// the line does not say it. Feature extraction: `Processed file [i/N]`; exhaustive matching:
/// `Matching block [a/A, b/B]`; sequential matching: `Matching image [i/N]`; mapping:
/// `Registering image #id (n)` (n images registered so far) and the initial pair (2).
pub fn stage_progress(line: &str) -> Option<(u64, Option<u64>)> {
    let bracket = |rest: &str| -> Option<Vec<(u64, u64)>> {
        let inner = rest.trim_start().strip_prefix('[')?.split(']').next()?;
        inner
            .split(',')
            .map(|part| {
                let (i, n) = part.trim().split_once('/')?;
                Some((i.trim().parse().ok()?, n.trim().parse().ok()?))
            })
            .collect()
    };
    let line = line.trim();
    if let Some(rest) = line
        .strip_prefix("Processed file")
        .or_else(|| line.strip_prefix("Matching image"))
    {
        let &[(i, n)] = bracket(rest)?.as_slice() else {
            return None;
        };
        return Some((i, Some(n)));
    }
    if let Some(rest) = line.strip_prefix("Matching block") {
        let &[(a, na), (b, nb)] = bracket(rest)?.as_slice() else {
            return None;
        };
        return Some(((a.saturating_sub(1)) * nb + b, Some(na * nb)));
    }
    if let Some(rest) = line.strip_prefix("Registering image #") {
        let count = rest.split_once('(')?.1.split_once(')')?.0;
        return Some((count.trim().parse().ok()?, None));
    }
    line.starts_with("Initializing with image pair")
        .then_some((2, None))
}

/// Runs `colmap <stage> <args>` with its stdout and stderr written to `log`, a progress bar
/// of `steps` steps named after the stage fed from its output ([`stage_progress`]), and
/// returns its exit status and the seconds it ran. An error when it cannot start.
pub fn run_stage(
    program: &Path,
    stage: &'static str,
    args: &[&std::ffi::OsStr],
    log: &Path,
    steps: u64,
) -> Result<(ExitStatus, f64)> {
    let start = Instant::now();
    let file = File::create(log).with_context(|| format!("cannot create {}", log.display()))?;
    let writer = Arc::new(Mutex::new(BufWriter::new(file)));
    let mut child = colmap_command(program, stage)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| anyhow!("cannot run COLMAP's {stage} ({}): {e}", program.display()))?;
    let bar = progress_bar(steps.max(1), &format!("COLMAP {stage}"));
    let done = Arc::new(Mutex::new(0u64));
    let readers: Vec<Box<dyn Read + Send>> = vec![
        Box::new(child.stdout.take().expect("piped stdout")),
        Box::new(child.stderr.take().expect("piped stderr")),
    ];
    let threads: Vec<_> = readers
        .into_iter()
        .map(|stream| {
            let (writer, bar, done) = (writer.clone(), bar.clone(), done.clone());
            std::thread::spawn(move || {
                for line in BufReader::new(stream).split(b'\n').map_while(|l| l.ok()) {
                    let mut w = writer.lock().unwrap_or_else(|e| e.into_inner());
                    let _ = w.write_all(&line).and_then(|()| w.write_all(b"\n"));
                    drop(w);
                    if let Some((now, _)) = stage_progress(&String::from_utf8_lossy(&line)) {
                        let mut done = done.lock().unwrap_or_else(|e| e.into_inner());
                        let now = now.min(steps);
                        if now > *done {
                            bar.inc(now - *done);
                            *done = now;
                        }
                    }
                }
            })
        })
        .collect();
    let status = child.wait();
    for t in threads {
        let _ = t.join();
    }
    bar.finish_and_clear();
    let flushed = writer.lock().unwrap_or_else(|e| e.into_inner()).flush();
    let status = status.with_context(|| format!("COLMAP's {stage} did not finish"))?;
    flushed.with_context(|| format!("cannot write {}", log.display()))?;
    Ok((status, start.elapsed().as_secs_f64()))
}

/// The last line of `log` that is not blank, for an error message.
pub fn last_line(log: &Path) -> String {
    std::fs::read(log)
        .map(|bytes| {
            String::from_utf8_lossy(&bytes)
                .lines()
                .rev()
                .map(str::trim)
                .find(|l| !l.is_empty())
                .unwrap_or("")
                .to_string()
        })
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_lines() {
        assert_eq!(stage_progress("Processed file [3/24]"), Some((3, Some(24))));
        assert_eq!(
            stage_progress("Matching block [2/3, 1/3] in 4.5s"),
            Some((4, Some(9)))
        );
        assert_eq!(
            stage_progress("Matching image [7/120]"),
            Some((7, Some(120)))
        );
        assert_eq!(stage_progress("Registering image #18 (4)"), Some((4, None)));
        assert_eq!(
            stage_progress("Initializing with image pair #20 and #10"),
            Some((2, None))
        );
        assert_eq!(stage_progress("  Features:        1281"), None);
    }
}
