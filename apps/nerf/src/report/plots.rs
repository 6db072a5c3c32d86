//! The report's plots: error or PSNR against time, drawn from the measured studies.

use super::box_study::{BoxRow, BoxStudy};
use super::lego_study::{LegoMethod, LegoStudy};
use super::line_plot::{LinePlot, Series};
use super::training_log::TrainingCurve;
use super::Report;

/// The box plot: each study's errors against seconds per frame, log-log.
pub(super) fn box_plot(report: &Report) -> LinePlot {
    let series = |label: &str, study: &BoxStudy, pick: &dyn Fn(&BoxRow) -> Option<f64>| Series {
        label: label.to_string(),
        points: study
            .rows
            .iter()
            .filter_map(|r| pick(r).map(|e| (r.seconds_per_frame, e)))
            .collect(),
    };
    LinePlot {
        title: format!(
            "Box, {0}x{0}: error against time per frame (8 to {1} samples per ray)",
            report.sizes.box_size,
            report.sizes.box_pts.last().copied().unwrap_or(0)
        ),
        x_label: "seconds per frame".into(),
        y_label: "error".into(),
        log_x: true,
        log_y: true,
        legend: plotters::prelude::SeriesLabelPosition::LowerLeft,
        series: vec![
            series(
                "hard box: mean |depth - analytic hit|",
                &report.hard_box,
                &|r| r.vs_analytic.map(|e| e.depth_mae),
            ),
            series(
                "hard box: colour RMSE vs analytic (grazing misses left out)",
                &report.hard_box,
                &|r| r.vs_analytic_clear.map(|e| e.color_rmse),
            ),
            series(
                "hard box: colour RMSE vs analytic, all pixels",
                &report.hard_box,
                &|r| r.vs_analytic.map(|e| e.color_rmse),
            ),
            series(
                "homework box: colour RMSE vs most samples",
                &report.homework_box,
                &|r| Some(r.vs_reference.color_rmse),
            ),
            series(
                "homework box: mean |depth| diff vs most samples",
                &report.homework_box,
                &|r| Some(r.vs_reference.depth_mae),
            ),
        ]
        .into_iter()
        .map(|mut s| {
            // A log axis cannot show an exact zero (the reference row itself).
            s.points.retain(|p| p.1 > 0.0);
            s
        })
        .collect(),
    }
}

/// The lego plot: PSNR against the ground truth against seconds per frame, one series per
/// method.
pub(super) fn lego_plot(study: &LegoStudy) -> LinePlot {
    LinePlot {
        title: format!(
            "Lego, {0}x{0}: PSNR against time per frame (samples per ray {1})",
            study.size,
            study
                .rows
                .iter()
                .map(|r| r.n_pts)
                .collect::<std::collections::BTreeSet<_>>()
                .iter()
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
        x_label: "seconds per frame".into(),
        y_label: "PSNR vs ground truth (dB)".into(),
        log_x: true,
        log_y: false,
        legend: plotters::prelude::SeriesLabelPosition::LowerRight,
        series: LegoMethod::ALL
            .into_iter()
            .filter(|method| study.rows.iter().any(|r| r.acceleration == *method))
            .map(|method| Series {
                label: method.name().to_string(),
                points: study
                    .rows
                    .iter()
                    .filter(|r| r.acceleration == method)
                    .map(|r| (r.seconds_per_frame, r.psnr_vs_truth))
                    .collect(),
            })
            .collect(),
    }
}

/// The training plot: test and training-batch PSNR against minutes of training, per log.
pub(super) fn training_plot(curves: &[&TrainingCurve]) -> LinePlot {
    let mut series = Vec::new();
    for c in curves {
        // The log's path without `.log.jsonl`: the run it belongs to.
        let path = c.log.display().to_string();
        let name = path.strip_suffix(".log.jsonl").unwrap_or(&path);
        if !c.test.is_empty() {
            series.push(Series {
                label: format!(
                    "{name}: test PSNR ({} views)",
                    c.test_views.map_or("?".into(), |n| n.to_string())
                ),
                points: c.test.iter().map(|(w, _, p)| (w / 60.0, *p)).collect(),
            });
        }
        series.push(Series {
            label: format!("{name}: training-batch PSNR (epoch mean)"),
            points: c.train.iter().map(|(w, _, p)| (w / 60.0, *p)).collect(),
        });
    }
    LinePlot {
        title: "Training: PSNR against wall-clock time".into(),
        x_label: "minutes of training".into(),
        y_label: "PSNR (dB)".into(),
        log_x: false,
        log_y: false,
        legend: plotters::prelude::SeriesLabelPosition::LowerRight,
        series,
    }
}
