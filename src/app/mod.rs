//! The application layer: config files, jobs, bench and report.

pub mod bench;
pub mod config;
pub mod evaluate;
pub mod jobs;
pub mod report;
pub mod runtime;
pub mod scene;
pub mod train;
pub mod train_box;
