//! Progress on stderr: an indicatif bar on a terminal.

use indicatif::{ProgressBar, ProgressStyle};

/// A progress bar on stderr (drawn only on a terminal).
pub fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

/// Prints `message` as a line above `bar`, or on stderr when the bar is hidden (stderr is not
/// a terminal, as when training runs in the background with its output in a file): indicatif
/// drops the lines of a hidden bar.
pub fn print_above(bar: &ProgressBar, message: &str) {
    if bar.is_hidden() {
        crate::core::term::note(message);
    } else {
        bar.println(message);
    }
}
