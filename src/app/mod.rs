//! The application layer: config files, jobs, bench and report.

pub mod bench;
pub mod camera_path;
#[cfg(feature = "cli")]
pub mod cli;
#[cfg(feature = "cli")]
pub mod cli_commands;
pub mod config;
pub mod evaluate;
pub mod export;
pub mod export_model;
pub mod jobs;
pub mod messages;
pub mod process;
#[cfg(feature = "cli")]
pub mod report;
pub mod scene;
pub mod train;
pub mod train_box;
#[cfg(feature = "cli")]
pub mod view;
#[cfg(feature = "cli")]
pub mod view_host;
#[cfg(feature = "cli")]
pub mod view_queue;
pub mod view_request;
pub mod yaml_bounds;
