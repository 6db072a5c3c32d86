//! Messages on stderr that never panic: a closed pipe or a full disk on stderr must not turn a
//! warning into a crash (`eprintln!` panics when the write fails). Also the library's own
//! messages (training progress, loaded files, warnings), which it emits through the `log`
//! facade, printed one per line by [`print_library_messages`].

use std::io::Write;

/// Writes `message` and a newline to stderr, ignoring write errors.
pub fn note(message: &str) {
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "{message}");
}

/// A number for a one-line message: 4 significant digits, in scientific notation when very
/// large or small (`1e300`, not 300 digits).
pub fn short_number(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e6).contains(&v.abs()) {
        let text = format!("{v:.3e}");
        // 1.000e300 → 1e300.
        match text.split_once('e') {
            Some((mantissa, exponent)) => {
                let mantissa = mantissa.trim_end_matches('0').trim_end_matches('.');
                format!("{mantissa}e{exponent}")
            }
            None => text,
        }
    } else {
        let text = format!("{v:.4}");
        let text = text.trim_end_matches('0').trim_end_matches('.');
        text.to_string()
    }
}

/// `error` and its chain of sources as the one line the `nerf` binary prints: each cause cut
/// to its first non-blank line, trimmed (Candle appends a backtrace to its errors' text when
/// `RUST_BACKTRACE` is set; some causes' text starts with a line break), blank ones left out,
/// joined by `": "`. The typed errors of the library's boundaries carry this line as their
/// message when they gather several layers of context.
pub fn error_line(error: &(dyn std::error::Error + 'static)) -> String {
    let causes: Vec<String> = std::iter::successors(Some(error), |e| e.source())
        .filter_map(|c| {
            let text = c.to_string();
            text.lines()
                .find(|l| !l.trim().is_empty())
                .map(|l| l.trim().to_string())
        })
        .collect();
    causes.join(": ")
}

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

/// Names as a message lists them: `a`, `a or b`, `a, b or c`.
pub fn or_list(names: &[&str]) -> String {
    match names.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        Some((last, _)) => last.to_string(),
        None => String::new(),
    }
}
