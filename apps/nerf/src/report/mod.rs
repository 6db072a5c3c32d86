//! `nerf report`: error against run time, measured on this machine and written as Markdown
//! with PNG plots.
//!
//! * **Box**: the box scene at `n_pts_per_ray` 8 … 1024, timed per frame, against the same
//!   scene at far more samples and, for a hard surface (β = 1e-4), against the analytic
//!   ray–box hit ([`nerf::eval::reference::analytic_hit`]).
//! * **Lego**: a trained checkpoint at several sample counts with each acceleration the
//!   renderer offers, against the ground truth and against the dense render.
//! * **Training**: test PSNR against wall-clock time, from training logs.
//!
//! The studies are typed values ([`BoxScene`] and [`BoxRender`], [`LegoMethod`] and
//! [`LegoRender`]) that make their own configs; rows carry the typed key they were measured
//! for, and display strings are made only where the report is written ([`mod@markdown`],
//! [`plots`]).

pub mod box_study;
pub mod lego_study;
mod line_plot;
pub mod markdown;
pub mod plots;
pub mod scoring;
pub mod training_log;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use candle_core::Device;
use serde::Serialize;

use crate::bench::{machine_info, MachineInfo};
use line_plot::{write_line_plot, LinePlot};
use plots::{box_plot, lego_plot, training_plot};

pub use box_study::{box_study, BoxScene, BoxStudy};
pub use lego_study::{lego_study, LegoMethod, LegoStudy};
pub use markdown::markdown;
pub use training_log::{read_training_log, TrainingCurve};

/// What `nerf report` measures and where it writes.
#[derive(Debug, Clone)]
pub struct ReportOptions {
    /// Directory for report.md, report.json and the plots.
    pub out_dir: PathBuf,
    /// CI-sized run: small images, fewer sample counts and views, one repeat.
    pub quick: bool,
    /// Trained NeRF for the lego section (skipped, with a note, when missing).
    pub checkpoint: PathBuf,
    /// Lego dataset (ground truth and test cameras).
    pub data_dir: PathBuf,
    /// Test views for the lego section (default 5, quick 2).
    pub views: Option<usize>,
    /// Training logs (`.log.jsonl`) to plot; missing ones are noted and skipped.
    pub training_logs: Vec<PathBuf>,
    /// A trained hash-grid field (the `lego_ngp` config's) for the lego section's hash-grid
    /// rows; none, or a missing file, leaves them out.
    pub ngp_checkpoint: Option<PathBuf>,
    /// Whether to measure the lego section. When true, a missing checkpoint or dataset is an
    /// error before anything is measured (see [`check_lego_inputs`]), not a silent omission.
    pub lego: bool,
}

/// An error naming what is missing when the lego section's checkpoint or dataset cannot be
/// read, with the working directory relative paths were taken from and how to go on.
pub fn check_lego_inputs(options: &ReportOptions) -> Result<()> {
    let cwd = std::env::current_dir()
        .map(|d| d.display().to_string())
        .unwrap_or_else(|_| "?".into());
    let relative = |p: &Path| {
        if p.is_relative() {
            format!(" (relative to the working directory {cwd})")
        } else {
            String::new()
        }
    };
    let to_go_on = "pass --checkpoint FILE and --data-dir DIR, or --no-lego to write the report \
                    without the lego section";
    if !options.checkpoint.is_file() {
        anyhow::bail!(
            "report: the lego section's checkpoint {} is not a file{}; {to_go_on}",
            options.checkpoint.display(),
            relative(&options.checkpoint)
        );
    }
    let transforms = options.data_dir.join("transforms_test.json");
    if !transforms.is_file() {
        anyhow::bail!(
            "report: the lego section's dataset {} has no transforms_test.json{}; {to_go_on}",
            options.data_dir.display(),
            relative(&options.data_dir)
        );
    }
    Ok(())
}

/// The 1-minute load average (`/proc/loadavg`), when the system tells it.
fn load_average() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    text.split_whitespace().next()?.parse().ok()
}

/// Sizes of a full or a quick run.
#[derive(Debug, Clone, Serialize)]
pub struct Sizes {
    /// Width and height of the box renders, in pixels.
    pub box_size: usize,
    /// Sample counts (`n_pts_per_ray`) of the box study's rows.
    pub box_pts: Vec<usize>,
    /// Samples per ray of the box reference render.
    pub box_reference_pts: usize,
    /// Surround views rendered for the box study (indices, taken modulo the number of poses).
    pub box_views: Vec<usize>,
    /// Width and height of the lego renders, in pixels.
    pub lego_size: usize,
    /// Sample counts (`n_pts_per_ray`) of the lego study's rows.
    pub lego_pts: Vec<usize>,
    /// Samples per ray of the dense lego reference render.
    pub lego_reference_pts: usize,
    /// Lego test views rendered (at most the split's size).
    pub lego_views: usize,
    /// Timed renders per measurement (the fastest counts).
    pub repeats: usize,
}

impl Sizes {
    /// The full report's sizes, or the CI-sized ones with `quick`; `views` overrides the
    /// number of lego test views.
    pub fn new(quick: bool, views: Option<usize>) -> Self {
        if quick {
            Self {
                box_size: 64,
                box_pts: vec![8, 16, 32, 64, 128, 256],
                box_reference_pts: 2048,
                box_views: vec![0],
                lego_size: 64,
                lego_pts: vec![32, 128],
                lego_reference_pts: 128,
                lego_views: views.unwrap_or(2),
                repeats: 1,
            }
        } else {
            Self {
                box_size: 256,
                box_pts: (3..=10).map(|k| 1 << k).collect(),
                box_reference_pts: 8192,
                box_views: vec![0, 10],
                lego_size: 128,
                lego_pts: vec![32, 64, 128, 256],
                lego_reference_pts: 128,
                lego_views: views.unwrap_or(5),
                repeats: 2,
            }
        }
    }
}

/// Everything a report holds (also written as report.json).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// The machine the report was measured on.
    pub machine: MachineInfo,
    /// Whether this is the CI-sized run.
    pub quick: bool,
    /// The sizes measured.
    pub sizes: Sizes,
    /// Wall-clock seconds the whole measurement took.
    pub seconds: f64,
    /// The system's 1-minute load average before and after the measurement (`None` where
    /// the system does not tell it): how busy the machine was, which the report can only
    /// state, not control.
    pub load_average: [Option<f64>; 2],
    /// The homework's box (β = [`HOMEWORK_BETA`]) against many samples.
    pub homework_box: BoxStudy,
    /// The hard box (β = [`HARD_BETA`]) against many samples and the analytic surface.
    pub hard_box: BoxStudy,
    /// The lego study, or why it was skipped.
    pub lego: std::result::Result<LegoStudy, String>,
    /// One training curve per log, or why the log could not be read.
    pub training: Vec<std::result::Result<TrainingCurve, String>>,
}

impl Report {
    /// The training curves whose logs could be read (those that could not are left out).
    pub fn readable_training_curves(&self) -> Vec<&TrainingCurve> {
        self.training
            .iter()
            .filter_map(|c| c.as_ref().ok())
            .collect()
    }
}

/// The training logs a report plots by default: the checkpoint's `.log.jsonl`, the
/// homework-trained model's, the shipped hash-grid model's, and a 2-minute hash-grid run from
/// scratch (`nerf train --config nerf_lego_ngp --minutes 2`).
pub fn default_training_logs(checkpoint: &Path) -> Vec<PathBuf> {
    vec![
        checkpoint.with_extension("log.jsonl"),
        PathBuf::from("checkpoints/homework/nerf_lego.log.jsonl"),
        PathBuf::from(nerf::config::SHIPPED_NGP_CHECKPOINT).with_extension("log.jsonl"),
        PathBuf::from(TWO_MINUTE_NGP_LOG),
    ]
}

/// The log of a 2-minute hash-grid training run from scratch, committed beside the shipped
/// checkpoints.
pub const TWO_MINUTE_NGP_LOG: &str = "checkpoints/ngp_lego_2min.log.jsonl";

/// Runs every measurement.
pub fn measure(options: &ReportOptions, device: &Device) -> Result<Report> {
    let start = Instant::now();
    let load_before = load_average();
    let sizes = Sizes::new(options.quick, options.views);
    let box_renders = 2 * (1 + sizes.box_pts.len());
    let lego_renders = 1 + (LegoMethod::ACCELERATIONS.len() + 1) * sizes.lego_pts.len();
    let progress = nerf::io::progress::progress_bar((box_renders + lego_renders) as u64, "report");
    let homework_box = box_study(BoxScene::Homework, &sizes, device, &progress)?;
    let hard_box = box_study(BoxScene::Hard, &sizes, device, &progress)?;
    let lego = if options.lego {
        lego_study(options, &sizes, device, &progress).map_err(|e| format!("{e:#}"))
    } else {
        Err("left out (--no-lego)".to_string())
    };
    progress.finish_and_clear();
    let training = options
        .training_logs
        .iter()
        .map(|p| read_training_log(p).map_err(|e| format!("{e:#}")))
        .collect();
    Ok(Report {
        machine: machine_info(),
        quick: options.quick,
        sizes,
        seconds: start.elapsed().as_secs_f64(),
        load_average: [load_before, load_average()],
        homework_box,
        hard_box,
        lego,
        training,
    })
}

/// Measures, then writes `report.md`, `report.json` and the plots into `options.out_dir`.
/// Returns the paths written.
pub fn write_report(options: &ReportOptions, device: &Device) -> Result<Vec<PathBuf>> {
    if options.lego {
        check_lego_inputs(options)?;
    }
    std::fs::create_dir_all(&options.out_dir)
        .with_context(|| format!("creating {}", options.out_dir.display()))?;
    nerf::io::output::remove_stale_temp_files(&options.out_dir);
    let report = measure(options, device)?;
    let mut written = Vec::new();
    let mut plots = Vec::new();
    let mut add_plot = |name: &str, file: &str, plot: LinePlot| -> Result<()> {
        let path = options.out_dir.join(file);
        write_line_plot(&path, &plot)?;
        written.push(path);
        plots.push((name.to_string(), file.to_string()));
        Ok(())
    };
    add_plot("box", "box_error_vs_time.png", box_plot(&report))?;
    if let Ok(l) = &report.lego {
        add_plot("lego", "lego_psnr_vs_time.png", lego_plot(l))?;
    }
    let curves = report.readable_training_curves();
    if !curves.is_empty() {
        add_plot(
            "training",
            "training_psnr_vs_time.png",
            training_plot(&curves),
        )?;
    }
    let md = options.out_dir.join("report.md");
    nerf::io::output::write_text(&md, &markdown(&report, &plots))?;
    written.push(md);
    let json = options.out_dir.join("report.json");
    nerf::io::output::write_text(&json, &serde_json::to_string_pretty(&report)?)?;
    written.push(json);
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use box_study::{BoxRow, HARD_BETA, HOMEWORK_BETA};
    use lego_study::LegoRow;
    use scoring::ImageError;

    fn error(x: f64) -> ImageError {
        ImageError {
            color_rmse: x,
            psnr: 30.0 - x,
            depth_mae: x / 2.0,
            depth_pixels: 7,
        }
    }

    fn box_study_of(beta: f64, hard: bool) -> BoxStudy {
        BoxStudy {
            beta,
            reference_pts: 2048,
            rows: [8usize, 16]
                .iter()
                .map(|&n| BoxRow {
                    n_pts: n,
                    seconds_per_frame: 0.01 * n as f64,
                    vs_reference: error(1.0 / n as f64),
                    vs_analytic: hard.then(|| error(2.0 / n as f64)),
                    vs_analytic_clear: hard.then(|| error(1.5 / n as f64)),
                    grazing_pixels: 3,
                })
                .collect(),
        }
    }

    /// A report of made-up measurements with a row of every lego method at 32 samples.
    fn made_up_report() -> Report {
        let rows = LegoMethod::ALL
            .iter()
            .enumerate()
            .map(|(k, &method)| LegoRow {
                acceleration: method,
                n_pts: 32,
                seconds_per_frame: 0.1 * (k + 1) as f64,
                psnr_vs_truth: 20.0 + k as f64,
                psnr_vs_dense: 30.0,
                evaluated: 1.0 / (k + 1) as f64,
            })
            .collect();
        Report {
            machine: MachineInfo {
                threads: 2,
                profile: "release",
                cpu: "Test CPU".into(),
            },
            quick: true,
            sizes: Sizes::new(true, None),
            seconds: 12.5,
            load_average: [Some(0.5), Some(1.75)],
            homework_box: box_study_of(HOMEWORK_BETA, false),
            hard_box: box_study_of(HARD_BETA, true),
            lego: Ok(LegoStudy {
                checkpoint: PathBuf::from("checkpoints/nerf_lego.safetensors"),
                size: 64,
                views: 2,
                reference_pts: 128,
                rows,
            }),
            training: vec![Err("missing log".into())],
        }
    }

    #[test]
    fn lego_rows_are_written_by_their_method_names() {
        let report = made_up_report();
        let md = markdown(&report, &[("lego".into(), "lego.png".into())]);
        for method in LegoMethod::ALL {
            let row = format!("| {} | 32 |", method.name());
            assert!(md.contains(&row), "{row} in {md}");
        }
        assert!(md.contains("The `coarse-to-fine (n/2 coarse + n/2 fine)` rows render"));
        assert!(md.contains(
            "The `hash grid (grid + early termination)` rows render the hash-grid model \
             `checkpoints/ngp_lego.safetensors`"
        ));
        assert!(md.contains("![lego](lego.png)"));
        let json = serde_json::to_value(&report).unwrap();
        let names: Vec<&str> = json["lego"]["Ok"]["rows"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["acceleration"].as_str().unwrap())
            .collect();
        let expected: Vec<&str> = LegoMethod::ALL.iter().map(|m| m.name()).collect();
        assert_eq!(names, expected);
        let Ok(lego) = &report.lego else {
            unreachable!()
        };
        let labels: Vec<String> = lego_plot(lego)
            .series
            .into_iter()
            .map(|s| s.label)
            .collect();
        assert_eq!(labels, expected);
    }
}
