//! Running COLMAP: COLMAP 4 through the `pycolmap` wheel (`pip install pycolmap`, no root
//! needed), driven by `pycolmap_stages.py` with the stage names and options of COLMAP's command
//! line, or a COLMAP program (`colmap` on `PATH`, or the one `NERF_COLMAP` names: Debian's
//! 3.8). Finding one, checking that it runs, and running one stage with its output written to
//! a log while a progress bar follows what the stage prints.

use crate::process::external_tool::ExternalTool;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};

use nerf::io::progress::progress_bar;

/// The environment variable naming the COLMAP executable (default: `colmap` on `PATH`).
pub const COLMAP_ENV: &str = "NERF_COLMAP";

/// The environment variable naming the Python that has `pycolmap` (default: `python3` on
/// `PATH`).
pub const PYTHON_ENV: &str = "NERF_PYTHON";

/// The script that runs COLMAP's stages through pycolmap, written into `OUT/colmap/`.
pub const PYCOLMAP_STAGES: &str = include_str!("pycolmap_stages.py");

/// The script's file name under `OUT/colmap/`.
pub const PYCOLMAP_SCRIPT: &str = "pycolmap_stages.py";

/// The COLMAP executable: `$NERF_COLMAP` when set, else `colmap` (looked up on `PATH`).
pub fn colmap_program() -> PathBuf {
    program_from_env(COLMAP_ENV, "colmap")
}

/// The Python executable: `$NERF_PYTHON` when set, else `python3` (looked up on `PATH`).
pub fn python_program() -> PathBuf {
    program_from_env(PYTHON_ENV, "python3")
}

fn program_from_env(env: &str, default: &str) -> PathBuf {
    std::env::var_os(env)
        .filter(|v| !v.is_empty())
        .map_or_else(|| PathBuf::from(default), PathBuf::from)
}

/// Which COLMAP runs the stages.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Colmap {
    /// COLMAP 4 through the `pycolmap` wheel: `PYTHON SCRIPT STAGE --Option value ...`.
    Pycolmap {
        /// The Python that imports pycolmap.
        python: PathBuf,
        /// [`PYCOLMAP_STAGES`] written out (see [`Colmap::write_script`]).
        script: PathBuf,
    },
    /// A COLMAP program: `PROGRAM STAGE --Option value ...`.
    Program(PathBuf),
}

/// Which COLMAP `nerf process` asks for (`--sfm`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SfmChoice {
    /// pycolmap when Python imports it and `NERF_COLMAP` does not name a program, else the
    /// COLMAP program.
    Auto,
    /// COLMAP 4 through the pycolmap wheel.
    Pycolmap,
    /// The COLMAP program (`colmap` or `NERF_COLMAP`).
    Program,
}

/// Whether `python` imports pycolmap.
fn imports_pycolmap(python: &Path) -> bool {
    Command::new(python)
        .args(["-c", "import pycolmap"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

impl Colmap {
    /// The COLMAP `choice` names, checked to run, its script to be written under `colmap`
    /// (the folder `OUT/colmap`, not created here). One-line errors say what is missing and
    /// how to install it.
    pub fn find(choice: SfmChoice, colmap: &Path) -> Result<Self> {
        let python = python_program();
        let pycolmap = || Colmap::Pycolmap {
            python: python.clone(),
            script: colmap.join(PYCOLMAP_SCRIPT),
        };
        match choice {
            SfmChoice::Pycolmap if imports_pycolmap(&python) => Ok(pycolmap()),
            SfmChoice::Pycolmap => bail!(
                "pycolmap is missing: `{}` cannot import it; install it with `pip install pycolmap` (COLMAP 4, no root needed) or set {PYTHON_ENV} to a Python that has it",
                python.display()
            ),
            // NERF_COLMAP set says which COLMAP to run.
            SfmChoice::Auto if std::env::var_os(COLMAP_ENV).is_some_and(|v| !v.is_empty()) => {
                Colmap::find(SfmChoice::Program, colmap)
            }
            SfmChoice::Auto if imports_pycolmap(&python) => Ok(pycolmap()),
            SfmChoice::Auto => {
                let program = colmap_program();
                check_colmap(&program).map_err(|_| {
                    anyhow!(
                        "COLMAP is missing: `{}` cannot import pycolmap and `{}` on PATH does not run; install COLMAP 4 with `pip install pycolmap` (no root needed) or COLMAP 3.8 with `sudo apt-get install colmap` (Debian/Ubuntu)",
                        python.display(),
                        program.display()
                    )
                })?;
                Ok(Colmap::Program(program))
            }
            SfmChoice::Program => {
                let program = colmap_program();
                check_colmap(&program)?;
                Ok(Colmap::Program(program))
            }
        }
    }

    /// Writes the pycolmap script into its folder (nothing for a program).
    pub fn write_script(&self) -> Result<()> {
        if let Colmap::Pycolmap { script, .. } = self {
            nerf::io::output::write_text(script, PYCOLMAP_STAGES)?;
        }
        Ok(())
    }

    /// Whether this is COLMAP 4 through pycolmap.
    pub fn is_pycolmap(&self) -> bool {
        matches!(self, Colmap::Pycolmap { .. })
    }

    /// What messages call it.
    pub fn describe(&self) -> String {
        match self {
            Colmap::Pycolmap { python, .. } => {
                format!("COLMAP 4 via pycolmap ({})", python.display())
            }
            Colmap::Program(program) => format!("the COLMAP program ({})", program.display()),
        }
    }

    /// A command running `stage`, with its environment: no display
    /// (`QT_QPA_PLATFORM=offscreen`), no input.
    fn command(&self, stage: &str) -> Command {
        let mut command = match self {
            Colmap::Pycolmap { python, script } => {
                let mut c = Command::new(python);
                c.arg(script);
                c
            }
            Colmap::Program(program) => Command::new(program),
        };
        command
            .arg(stage)
            .env("QT_QPA_PLATFORM", "offscreen")
            .stdin(Stdio::null());
        command
    }
}

/// Checks that `program` runs (`colmap help`); the one-line error says that COLMAP is
/// missing and how to install it.
pub fn check_colmap(program: &Path) -> Result<()> {
    let colmap = ExternalTool {
        name: "COLMAP",
        env: COLMAP_ENV,
        package: "colmap",
    };
    colmap.check(Colmap::Program(program.into()).command("help"), program)
}

/// A line of COLMAP's output without glog's prefix (`I20261128 00:18:41.99 140 file.cc:270] `),
/// which COLMAP 4 puts before its progress lines.
fn without_log_prefix(line: &str) -> &str {
    let line = line.trim();
    let glog = line
        .chars()
        .next()
        .is_some_and(|c| matches!(c, 'I' | 'W' | 'E' | 'F'))
        && line[1..].starts_with(|c: char| c.is_ascii_digit());
    match line.split_once("] ") {
        Some((_, rest)) if glog => rest.trim(),
        _ => line,
    }
}

/// Progress a line of COLMAP's output reports: `(done, of)` steps, where `of` is `None` when
/// the line does not say it. Feature extraction: `Processed file [i/N]`; exhaustive matching:
/// `Matching block [a/A, b/B]` (COLMAP 4: `Processing block`); sequential matching: `Matching
/// image [i/N]` (COLMAP 4: `Processing image`); mapping: `Registering image #id (n)` (n images
/// registered so far) and the initial pair (2). COLMAP 4's glog prefix is skipped.
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
    let line = without_log_prefix(line);
    if let Some(rest) = line
        .strip_prefix("Processed file")
        .or_else(|| line.strip_prefix("Matching image"))
        .or_else(|| line.strip_prefix("Processing image"))
    {
        let &[(i, n)] = bracket(rest)?.as_slice() else {
            return None;
        };
        return Some((i, Some(n)));
    }
    if let Some(rest) = line
        .strip_prefix("Matching block")
        .or_else(|| line.strip_prefix("Processing block"))
    {
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

/// Runs `colmap`'s `<stage> <args>` with its stdout and stderr written to `log`, a progress bar
/// of `steps` steps named after the stage fed from its output ([`stage_progress`]), and
/// returns its exit status and the seconds it ran. An error when it cannot start.
pub fn run_stage(
    colmap: &Colmap,
    stage: &'static str,
    args: &[&std::ffi::OsStr],
    log: &Path,
    steps: u64,
) -> Result<(ExitStatus, f64)> {
    let start = Instant::now();
    let file = File::create(log).with_context(|| format!("cannot create {}", log.display()))?;
    let writer = Arc::new(Mutex::new(BufWriter::new(file)));
    let mut child = colmap
        .command(stage)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| anyhow!("cannot run COLMAP's {stage} ({}): {e}", colmap.describe()))?;
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
        // COLMAP 4 (pycolmap): glog's prefix and its own words.
        assert_eq!(
            stage_progress(
                "I20261128 00:18:41.995021 140565869995712 feature_extraction.cc:270] Processed file [1/47]"
            ),
            Some((1, Some(47)))
        );
        assert_eq!(
            stage_progress(
                "I20261128 00:18:51.004439 1397 pairing.cc:214] Processing block [2/2, 1/2]"
            ),
            Some((3, Some(4)))
        );
        assert_eq!(
            stage_progress(
                "I20261128 00:19:06.580503 1401 pairing.cc:562] Processing image [5/47]"
            ),
            Some((5, Some(47)))
        );
        assert_eq!(stage_progress("Processing block [1/3]"), None);
    }
}
