//! The `nerf` command line: parses arguments and calls the library.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use candle_core::Device;
use clap::{Parser, Subcommand};

use nerf::config::{Config, ImplicitFunctionConfig};

#[derive(Parser)]
#[command(
    name = "nerf",
    version,
    about = "Differentiable volume rendering and NeRF on Candle (pytorch3d conventions)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene's surround views and visualisations into an output directory.
    Render {
        /// Config name (configs/NAME.yaml or built-in) or path to a YAML file.
        #[arg(long)]
        config: String,
        /// Output directory.
        #[arg(long, default_value = "images")]
        out_dir: PathBuf,
        /// Also write color_{i:03}.npy (H,W,3) and depth_{i:03}.npy (H,W) float32 per frame.
        #[arg(long)]
        raw: bool,
        /// Hydra-style overrides, e.g. sampler.n_pts_per_ray=32 data.image_size=[200,150].
        overrides: Vec<String>,
    },
    /// Time the main jobs and print a table (or JSON).
    Bench {
        /// Config of the SDF scene to time.
        #[arg(long, default_value = "box")]
        config: String,
        /// Repeats per measurement (the best is reported).
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// Hydra-style overrides for the config.
        overrides: Vec<String>,
    },
}

fn run(cli: Cli) -> Result<()> {
    let device = Device::Cpu;
    match cli.command {
        Command::Render {
            config,
            out_dir,
            raw,
            overrides,
        } => {
            let config = Config::load(&config, &overrides)?;
            let written = match &config.implicit_function {
                ImplicitFunctionConfig::SdfVolume(_) => {
                    nerf::scene::render_sdf_scene(&config, &out_dir, raw, &device)?
                }
                ImplicitFunctionConfig::Nerf(_) => anyhow::bail!(
                    "implicit_function.type: nerf rendering is not available in this build"
                ),
            };
            for p in written {
                println!("wrote {}", p.display());
            }
        }
        Command::Bench {
            config,
            repeats,
            json,
            overrides,
        } => {
            let config = Config::load(&config, &overrides)?;
            let report = nerf::bench::run_benchmarks(&config, repeats, &device)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                print!("{}", nerf::bench::format_table(&report));
            }
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    nerf::tune_allocator();
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line: the chain of causes joined by ": ".
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
