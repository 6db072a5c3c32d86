//! The application layer: config files, jobs, bench and report.

pub mod bench;
pub mod config;
pub mod report;
pub mod scene;
