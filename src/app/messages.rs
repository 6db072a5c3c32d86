//! The `nerf` command's stderr: the library's messages (training progress, loaded files,
//! warnings), which it emits through the `log` facade, printed one per line.

use crate::core::term::note;

struct StderrLines;

impl log::Log for StderrLines {
    fn enabled(&self, metadata: &log::Metadata) -> bool {
        metadata.level() <= log::Level::Info
    }

    fn log(&self, record: &log::Record) {
        if self.enabled(record.metadata()) {
            note(&record.args().to_string());
        }
    }

    fn flush(&self) {}
}

/// Prints the library's messages of level info and above on stderr, one per line (never
/// panicking on a closed stderr). Does nothing when a logger is already installed.
pub fn print_library_messages() {
    static LOGGER: StderrLines = StderrLines;
    if log::set_logger(&LOGGER).is_ok() {
        log::set_max_level(log::LevelFilter::Info);
    }
}
