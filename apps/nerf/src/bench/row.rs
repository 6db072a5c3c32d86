//! One row of `nerf bench`: what was timed, how long it took, and what that is per second;
//! and what the rows that render the trained lego models need. Shared by the rows of
//! [`crate::bench`] and the hash-grid rows of [`crate::bench::hash_grid_rows`].

use serde::Serialize;

use nerf::core::image::RgbImage;
use nerf::core::metrics::mean_psnr;
use nerf::render::view::RenderedView;

/// One benchmark result.
#[derive(Debug, Clone, Serialize)]
pub struct BenchResult {
    /// Name of the benchmark, e.g. `box render`.
    pub name: String,
    /// What was timed, in words.
    pub work: String,
    /// Best wall-clock seconds over the repeats.
    pub seconds: f64,
    /// Every repeat's seconds.
    pub runs: Vec<f64>,
    /// PyTorch CPU figure for the same work on the reference 2-core machine, when known.
    pub pytorch_seconds: Option<f64>,
    /// Error of this run against a reference computation, with its unit, when measured.
    pub error: Option<String>,
    /// Samples, rays and FLOP per second, with the fraction of the machine's matrix-multiply
    /// rate, for the rows that measure them ([`crate::bench::hash_grid_rows`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub throughput: Option<Throughput>,
}

/// Throughput of a row: what it processed per second and how many floating-point operations
/// per second that is, against the matrix-multiply rate measured in the same run.
#[derive(Debug, Clone, Default, Serialize, PartialEq)]
pub struct Throughput {
    /// Rays per second, when the row renders or trains on rays.
    pub rays_per_second: Option<f64>,
    /// Samples drawn per second (rays × samples per ray).
    pub drawn_samples_per_second: Option<f64>,
    /// Samples at which the field was evaluated, per second.
    pub evaluated_samples_per_second: Option<f64>,
    /// The FLOP count of one evaluated sample the row's GFLOP/s assume ([`crate::bench::hash_grid_rows::NgpFlops`]).
    pub flop_per_evaluated_sample: Option<f64>,
    /// Random table rows read per second ([`crate::bench::memory`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub row_reads_per_second: Option<f64>,
    /// Random hash-table row accesses per second of a hash-grid row ([`crate::bench::hash_grid_rows::NgpFlops`]
    /// counts them).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub table_rows_per_second: Option<f64>,
    /// `table_rows_per_second` over the same run's random-read rate from a table of 16
    /// levels ([`crate::bench::memory`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fraction_of_random_reads: Option<f64>,
    /// Useful floating-point operations per second, in 10^9 (0 for rows that count none).
    pub gflops: f64,
    /// `gflops` over the MLP-shaped matrix product's rate (65536×64 by 64×64).
    pub fraction_of_mlp_gemm: Option<f64>,
    /// `gflops` over the large square matrix product's rate.
    pub fraction_of_square_gemm: Option<f64>,
}

impl Throughput {
    /// One line for the table, e.g. `1.2M evaluated samples/s, …; 60 GFLOP/s = 40% of the
    /// MLP gemm`.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        let si = |v: f64| {
            if v >= 1e9 {
                format!("{:.2}G", v / 1e9)
            } else if v >= 1e6 {
                format!("{:.2}M", v / 1e6)
            } else if v >= 1e3 {
                format!("{:.1}k", v / 1e3)
            } else {
                format!("{v:.0}")
            }
        };
        if let Some(v) = self.evaluated_samples_per_second {
            parts.push(format!("{} evaluated samples/s", si(v)));
        }
        if let Some(v) = self.drawn_samples_per_second {
            parts.push(format!("{} drawn samples/s", si(v)));
        }
        if let Some(v) = self.rays_per_second {
            parts.push(format!("{} rays/s", si(v)));
        }
        if let Some(v) = self.row_reads_per_second {
            parts.push(format!("{} random row reads/s", si(v)));
        }
        if let Some(v) = self.table_rows_per_second {
            let mut table = format!("{} table rows/s", si(v));
            if let Some(f) = self.fraction_of_random_reads {
                table += &format!(" = {:.1}% of the random-read rate", 100.0 * f);
            }
            parts.push(table);
        }
        if self.gflops == 0.0 && !parts.is_empty() {
            return parts.join(", ");
        }
        let mut rate = format!("{:.1} GFLOP/s", self.gflops);
        if let Some(f) = self.fraction_of_mlp_gemm {
            rate += &format!(" = {:.1}% of the MLP-shaped gemm", 100.0 * f);
        }
        if let Some(f) = self.fraction_of_square_gemm {
            rate += &format!(" ({:.1}% of the square)", 100.0 * f);
        }
        if parts.is_empty() {
            rate
        } else {
            format!("{}; {rate}", parts.join(", "))
        }
    }
}

/// What the trained-NeRF benchmark renders: a checkpoint, and the lego test split when
/// available (otherwise the surround views, compared with the dense render only).
#[derive(Debug, Clone)]
pub struct LegoBench {
    /// Trained NeRF checkpoint to render.
    pub checkpoint: std::path::PathBuf,
    /// Lego dataset directory (for the test split's cameras and images).
    pub data_dir: std::path::PathBuf,
    /// Views to render (the first of the test split).
    pub views: usize,
    /// CI-sized: the whole-command rows are left out, the hash-grid rows take fewer steps
    /// and repeats.
    pub quick: bool,
    /// Timed steps of each hash-grid training row (`None`: 24 at the shipped samples per step,
    /// 8 at 2^18, 2 when `quick`).
    pub train_steps: Option<usize>,
}

/// Mean over views of the PSNR of each frame's colour against its image.
pub fn mean_psnr_of_views(frames: &[RenderedView], images: &[RgbImage]) -> f64 {
    mean_psnr(&frames.iter().map(|f| &f.color).collect::<Vec<_>>(), images)
}
