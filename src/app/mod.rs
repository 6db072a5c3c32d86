//! The application layer: config files, jobs, bench and report.

pub mod bench;
pub mod config;
pub mod evaluate;
#[cfg(feature = "cli")]
pub mod report;
pub mod runtime;
pub mod scene;
pub mod train;
