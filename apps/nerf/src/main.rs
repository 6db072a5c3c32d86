//! The `nerf` command line: parses arguments ([`crate::cli`]) and calls the subcommand's
//! function ([`crate::commands`]); here only the allocator and the exit codes.

mod bench;
mod cli;
mod commands;
mod eval;
mod export;
mod limits;
mod process;
#[cfg(test)]
mod readme_commands;
mod render;
mod report;
mod timing;
mod train;
mod view;
mod worker_pool;

use std::process::ExitCode;

use anyhow::Result;
use clap::Parser;

use crate::cli::{Cli, Command};
use crate::commands::{StdoutError, Stopped};

/// mimalloc keeps freed segments for reuse: Candle allocates a fresh buffer of up to tens of
/// megabytes per op, and an allocator that returns each to the OS pays page faults on the next
/// op (`nerf::tune_allocator` does the same for glibc, for programs on the system allocator).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Exit code for a closed stdout pipe: 128 + SIGPIPE, as a shell reports a process that
/// SIGPIPE ended, so `nerf ... | head` ends quietly and scripts can still tell.
const BROKEN_PIPE_EXIT: u8 = 141;

/// Exit code of a run stopped by SIGINT or SIGTERM (128 + SIGINT, as shells report it).
const STOPPED_EXIT: u8 = 130;

fn run(cli: Cli) -> Result<()> {
    nerf::kernels::set_kernel_choice(cli.kernels.into());
    let device = cli.device.open()?;
    match cli.command {
        Command::Run(args) => commands::run(args, &device),
        Command::Render(args) => commands::render(args, &device),
        Command::Train(args) => commands::train(args, &device),
        Command::Targets(args) => commands::targets(args, &device),
        Command::Eval(args) => commands::eval(args, &device),
        Command::ImportTorch(args) => commands::import_torch(args),
        Command::Bench(args) => commands::bench(args, &device),
        Command::Report(args) => commands::report(args, &device),
        Command::View(args) => commands::view(args, &device),
        Command::Process(args) => commands::process(args, &device),
        Command::Export { what } => commands::export(what, &device),
    }
}

/// The two settings the library takes from its program rather than the environment:
/// `NERF_PROGRESS_SECONDS` (seconds between plain progress lines off a terminal; the tests set
/// 0) and `NERF_FAULT_WRITE_DELAY_MS` (a pause inside every atomic write, for the tests that
/// kill a run mid-write). A value that does not parse is ignored.
fn read_test_settings() {
    let read = |name: &str| std::env::var(name).ok();
    if let Some(seconds) = read("NERF_PROGRESS_SECONDS").and_then(|v| v.parse::<f64>().ok()) {
        nerf::io::progress::set_plain_line_seconds(seconds);
    }
    if let Some(ms) = read("NERF_FAULT_WRITE_DELAY_MS").and_then(|v| v.parse::<u64>().ok()) {
        nerf::io::output::set_write_delay_for_tests(ms);
    }
}

fn main() -> ExitCode {
    // Keep freed mimalloc segments instead of returning them to the OS after a short delay:
    // training allocates and frees large activations every op, and each one returned costs
    // page faults when the next op takes it back (measured: docs/speed-and-report.md#allocators).
    // SAFETY: sets a process-wide allocator option before any worker threads start.
    // The binding does not export these two enum values of mimalloc v2's `mi_option_e`.
    const MI_OPTION_ARENA_EAGER_COMMIT: libmimalloc_sys::mi_option_t = 4;
    const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;
    unsafe {
        libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1);
        libmimalloc_sys::mi_option_set(MI_OPTION_ARENA_EAGER_COMMIT, 1);
    }
    // Candle runs its element-wise ops on a pool of its own beside rayon's, whose caller
    // spin-waits for the pool's workers: with rayon's workers also busy, on a machine of few
    // cores those spins took a large share of a training step's cycles. One thread for
    // Candle's element-wise ops (its matmuls still use every thread; our fused kernels use
    // rayon's) makes both the hash-grid and the NeRF training step faster (measured:
    // docs/speed-and-report.md#element-wise-ops-on-one-thread). A user's CANDLE_NUM_THREADS
    // wins.
    if std::env::var_os("CANDLE_NUM_THREADS").is_none() {
        std::env::set_var("CANDLE_NUM_THREADS", "1");
    }
    read_test_settings();
    nerf::core::term::print_library_messages();
    let cli = Cli::parse();
    // The command's serial work shares the pool's threads instead of competing with them.
    let result = worker_pool::on_own_pool(|| run(cli));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            if let Some(Stopped(message)) = e.downcast_ref::<Stopped>() {
                nerf::core::term::note(message);
                return ExitCode::from(STOPPED_EXIT);
            }
            if let Some(StdoutError(io)) = e.downcast_ref::<StdoutError>() {
                if io.kind() == std::io::ErrorKind::BrokenPipe {
                    return ExitCode::from(BROKEN_PIPE_EXIT);
                }
            }
            // One line: the chain of causes joined by ": ", each cut to its first non-blank
            // line (the library's rule, which its typed errors' messages follow too).
            let line = nerf::core::term::error_line(e.as_ref());
            nerf::core::term::note(&format!("error: {line}"));
            ExitCode::FAILURE
        }
    }
}
