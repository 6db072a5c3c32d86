//! Messages on stderr that never panic: a closed pipe or a full disk on stderr must not turn a
//! warning into a crash (`eprintln!` panics when the write fails).

use std::io::Write;

/// Writes `message` and a newline to stderr, ignoring write errors.
pub fn note(message: &str) {
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "{message}");
}
