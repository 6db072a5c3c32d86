//! The report as Markdown: what was measured, how, and the tables; the one place where the
//! studies' values become text.

use std::fmt::Write as _;

use super::box_study::{BoxRow, BoxStudy};
use super::lego_study::LegoMethod;
use super::scoring::{log_log_slope, GRAZING_BETAS};
use super::training_log::minutes_to_reach;
use super::Report;
use crate::bench::MachineInfo;

fn machine_line(m: &MachineInfo) -> String {
    format!(
        "Machine: {}, {} threads, {} build.",
        m.cpu, m.threads, m.profile
    )
}

fn fmt_db(v: f64) -> String {
    if v.is_infinite() {
        "exact".into()
    } else if v.is_nan() {
        "—".into()
    } else {
        format!("{v:.2}")
    }
}

fn box_table(out: &mut String, study: &BoxStudy, analytic: bool) {
    if analytic {
        out.push_str("| samples per ray | seconds per frame | colour RMSE vs analytic, all pixels | colour RMSE vs analytic, grazing misses left out | PSNR of the same (dB) | mean abs. depth error vs analytic hit | colour RMSE vs most samples | mean abs. depth diff vs most samples |\n|---|---|---|---|---|---|---|---|\n");
    } else {
        out.push_str("| samples per ray | seconds per frame | colour RMSE vs most samples | PSNR vs most samples (dB) | mean abs. depth diff vs most samples |\n|---|---|---|---|---|\n");
    }
    for r in &study.rows {
        let e = &r.vs_reference;
        match (&r.vs_analytic, &r.vs_analytic_clear, analytic) {
            (Some(a), Some(c), true) => {
                let _ = writeln!(
                    out,
                    "| {} | {:.4} | {:.2e} | {:.2e} | {} | {:.2e} | {:.2e} | {:.2e} |",
                    r.n_pts,
                    r.seconds_per_frame,
                    a.color_rmse,
                    c.color_rmse,
                    fmt_db(c.psnr),
                    a.depth_mae,
                    e.color_rmse,
                    e.depth_mae
                );
            }
            _ => {
                let _ = writeln!(
                    out,
                    "| {} | {:.4} | {:.2e} | {} | {:.2e} |",
                    r.n_pts,
                    r.seconds_per_frame,
                    e.color_rmse,
                    fmt_db(e.psnr),
                    e.depth_mae
                );
            }
        }
    }
}

/// The report as Markdown, plots referenced by file name.
pub fn markdown(report: &Report, plots: &[(String, String)]) -> String {
    let mut out = String::new();
    let m = machine_line(&report.machine);
    let _ = writeln!(
        out,
        "# nerf report: error against run time\n\nMade by `nerf report{}` in {:.0} s. {m} \
         Times are wall-clock seconds on this machine; {} Errors are measured, not \
         estimated.\n",
        if report.quick { " --quick" } else { "" },
        report.seconds,
        load_sentence(report.load_average, report.machine.threads)
    );
    let plot = |name: &str| plot_link(plots, name);

    box_section(&mut out, report, &plot("box"), &m);
    lego_section(&mut out, report, &plot("lego"), &m);
    training_section(&mut out, report, &plot("training"));
    out
}

/// What the load average says of the timings: other work on the machine slows them, and the
/// report cannot know of it otherwise.
fn load_sentence(load: [Option<f64>; 2], threads: usize) -> String {
    match load {
        [Some(before), Some(after)] => format!(
            "the 1-minute load average was {before:.2} before the run and {after:.2} after it \
             (the run's own {threads} threads count towards the second; a first figure well \
             above 0 means other work shared the cores)."
        ),
        _ => "the load on the machine during the run is unknown (no /proc/loadavg).".into(),
    }
}

/// A Markdown image link to the plot named `name`, or nothing when it was not drawn.
fn plot_link(plots: &[(String, String)], name: &str) -> String {
    plots
        .iter()
        .find(|(n, _)| n == name)
        .map(|(n, f)| format!("![{n}]({f})\n\n"))
        .unwrap_or_default()
}

/// The box section: hard box against the analytic hit, homework box against many samples.
fn box_section(out: &mut String, report: &Report, plot: &str, m: &str) {
    let s = &report.sizes;
    let _ = writeln!(
        out,
        "## Box: samples per ray against error\n\n{m} Image {0}x{0}, view(s) {1:?} of the 20 \
         surround views, fastest of {2} run(s) per frame. Deterministic stratified depths on \
         [0, 5] (the homework's), the last sample's delta 1e10.\n",
        s.box_size, s.box_views, s.repeats
    );
    out.push_str(plot);
    // (samples per ray, error) of the hard box's rows that have the error.
    let hard_series = |error: &dyn Fn(&BoxRow) -> Option<f64>| -> Vec<(f64, f64)> {
        let rows = report.hard_box.rows.iter();
        rows.filter_map(|r| error(r).map(|e| (r.n_pts as f64, e)))
            .collect()
    };
    let hard_depth = hard_series(&|r| r.vs_analytic.map(|a| a.depth_mae));
    let hard_color = hard_series(&|r| r.vs_analytic_clear.map(|a| a.color_rmse));
    let grazing = report.hard_box.rows.first().map_or(0, |r| r.grazing_pixels);
    let pixels = s.box_size * s.box_size * s.box_views.len();
    let slope = |p: &[(f64, f64)]| log_log_slope(p).map_or("-".into(), |v| format!("{v:.2}"));
    let _ = writeln!(
        out,
        "### Hard box (β = {}), against the analytic ray–box hit\n\nWith β this small the \
         surface is a step: a sample's density is 0 outside and 1 (σ = ∞, opaque) inside, so \
         the render converges to the analytic surface. Colour is compared over all pixels \
         (a miss is black), depth over the pixels whose ray hits the box (a ray that only grazes an \
         edge crosses no volume and counts as a miss). The depth error falls as n^{} and the \
         colour error, grazing misses left out, as n^{} (least-squares slopes over the table; \
         the sample spacing is 5/n).\n\n\
         Grazing misses are rays that pass within {}β of the surface without entering it \
         ({grazing} of the {pixels} pixels here). Every sample there has a density near ½, and \
         the homework's σ = −ln(1 − density)/Δ gives each sample that opacity whatever the \
         spacing, so these rays turn opaque as samples are added instead of converging to a \
         miss: the colour error over all pixels stops falling at high sample counts because of \
         them.{} The last two columns compare with {} samples per ray.\n",
        report.hard_box.beta,
        slope(&hard_depth),
        slope(&hard_color),
        GRAZING_BETAS,
        if s.box_size == 256 {
            " (At 256×256 the box's silhouette edges, at NDC ±7/17, fall exactly on pixel \
             rows and columns: 1 − 2·75/255 = 7/17.)"
        } else {
            ""
        },
        report.hard_box.reference_pts
    );
    box_table(out, &report.hard_box, true);
    let _ = writeln!(
        out,
        "\n### Homework box (β = {}), against {} samples per ray\n\nThe homework's \
         density → σ rule, σ = −ln(1 − density)/Δ, makes each sample's opacity \
         1 − exp(−σΔ) equal to its density whatever the spacing Δ. More samples therefore \
         means more opacity in front of the surface, not a finer estimate of the same \
         integral: the image has no limit as n grows (the soft shell outside the surface keeps \
         getting more opaque). \
         The columns below are differences to the {1}-sample render, which only show how \
         far each sample count is from that one; they do not shrink to a converged answer.\n",
        report.homework_box.beta, report.homework_box.reference_pts
    );
    box_table(out, &report.homework_box, false);
    out.push('\n');
}

/// The lego section: accelerations and samples per ray.
fn lego_section(out: &mut String, report: &Report, plot: &str, m: &str) {
    let s = &report.sizes;
    out.push_str("## Lego: accelerations and samples per ray\n\n");
    match &report.lego {
        Ok(l) => {
            let _ = writeln!(
                out,
                "{m} Checkpoint `{0}`, {1}x{1}, the first {2} test view(s), fastest of {3} \
                 run(s) per frame. PSNR against the ground truth (on black) and against the \
                 dense render at {4} samples per ray (the trained count). The occupancy grid \
                 is part of the shipped model (it was trained with it), so the dense render \
                 shows ghost density the grid removes and scores lower against the ground \
                 truth.\n",
                l.checkpoint.display(),
                l.size,
                l.views,
                s.repeats,
                l.reference_pts
            );
            let (coarse_to_fine, hash_grid) = (LegoMethod::CoarseToFine, LegoMethod::HashGrid);
            if l.rows.iter().any(|r| r.acceleration == coarse_to_fine) {
                let _ = writeln!(
                    out,
                    "The `{}` rows render the same MLP densely in two \
                     passes (`sampler.n_pts_per_ray_fine`, pytorch3d's NeRF project's \
                     hierarchical sampling with one network): n/2 stratified samples, then \
                     n/2 more drawn from their weights, the fine pass evaluating all n. \
                     The field is evaluated at 150% of the n samples a ray keeps; compare \
                     the rows at equal seconds per frame.\n",
                    coarse_to_fine.name()
                );
            }
            if l.rows.iter().any(|r| r.acceleration == hash_grid) {
                let _ = writeln!(
                    out,
                    "The `{}` rows render the hash-grid model `{}` (config \
                     `lego_ngp`) on the same views; it has no dense reference.\n",
                    hash_grid.name(),
                    nerf::config::SHIPPED_NGP_CHECKPOINT
                );
            }
            out.push_str(plot);
            out.push_str("| acceleration | samples per ray | seconds per frame | PSNR vs ground truth (dB) | PSNR vs dense render (dB) | field evaluated at |\n|---|---|---|---|---|---|\n");
            for r in &l.rows {
                let _ = writeln!(
                    out,
                    "| {} | {} | {:.3} | {:.2} | {} | {:.1}% |",
                    r.acceleration.name(),
                    r.n_pts,
                    r.seconds_per_frame,
                    r.psnr_vs_truth,
                    fmt_db(r.psnr_vs_dense),
                    100.0 * r.evaluated
                );
            }
            out.push('\n');
        }
        Err(e) => {
            let _ = writeln!(out, "Skipped: {e}.\n");
        }
    }
}

/// The training section: PSNR against wall-clock time from the logs.
fn training_section(out: &mut String, report: &Report, plot: &str) {
    out.push_str("## Training: PSNR against wall-clock time\n\n");
    let curves = report.readable_training_curves();
    if !curves.is_empty() {
        out.push_str(
            "From the training logs: wall-clock seconds as the run logged them (evaluation \
             excluded), on the machine that trained the model (the 2-core development \
             machine, release build). Test PSNR is logged only by runs with \
             `training.eval_views`.\n\n",
        );
        out.push_str(plot);
        out.push_str("| log | epochs | minutes | last test PSNR (dB) | minutes to 20 / 22 / 24 / 25 / 26 / 27 dB test PSNR | last training-batch PSNR (dB) |\n|---|---|---|---|---|---|\n");
        for c in &curves {
            let last_epoch = c.train.last().map_or(0, |t| t.1 + 1);
            let minutes = c
                .train
                .last()
                .map(|t| t.0)
                .into_iter()
                .chain(c.test.last().map(|t| t.0))
                .fold(0.0, f64::max)
                / 60.0;
            let reach = [20.0, 22.0, 24.0, 25.0, 26.0, 27.0]
                .iter()
                .map(|t| {
                    minutes_to_reach(&c.test, *t).map_or("-".into(), |(m, _)| format!("{m:.1}"))
                })
                .collect::<Vec<_>>()
                .join(" / ");
            let _ = writeln!(
                out,
                "| `{}` | {} | {:.1} | {} | {} | {} |",
                c.log.display(),
                last_epoch,
                minutes,
                c.test
                    .last()
                    .map_or("-".into(), |t| format!("{:.2} (epoch {})", t.2, t.1)),
                if c.test.is_empty() { "-".into() } else { reach },
                c.train.last().map_or("-".into(), |t| format!("{:.2}", t.2)),
            );
        }
        out.push('\n');
    }
    for e in report.training.iter().filter_map(|c| c.as_ref().err()) {
        let _ = writeln!(out, "Skipped a training log: {e}.\n");
    }
}
