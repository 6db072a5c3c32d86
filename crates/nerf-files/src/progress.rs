//! Progress on stderr: an indicatif bar on a terminal (with the `bars` feature, which the
//! `nerf` command turns on); without the feature, or off a terminal, no bar is drawn and
//! [`Progress::println`] writes plain lines.
//! A [`progress_bar`] off a terminal also prints a plain `what: done/len after T s` line every
//! [`plain_line_seconds`], so a long render in the background shows that it is moving.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Seconds between plain progress lines when stderr is not a terminal, as f64 bits (10 s
/// until [`set_plain_line_seconds`] says otherwise).
static PLAIN_LINE_SECONDS: AtomicU64 = AtomicU64::new(0x4024_0000_0000_0000);

/// Seconds between plain progress lines when stderr is not a terminal (10 unless the program
/// set it with [`set_plain_line_seconds`]; 0 prints a line per step).
pub fn plain_line_seconds() -> f64 {
    f64::from_bits(PLAIN_LINE_SECONDS.load(Ordering::Relaxed))
}

/// Sets [`plain_line_seconds`] for the whole process (the `nerf` command reads it from
/// `NERF_PROGRESS_SECONDS`). A negative or non-finite value is ignored.
pub fn set_plain_line_seconds(seconds: f64) {
    if seconds.is_finite() && seconds >= 0.0 {
        PLAIN_LINE_SECONDS.store(seconds.to_bits(), Ordering::Relaxed);
    }
}

/// Plain progress lines of a hidden bar: its label, start and the time of the last line.
#[derive(Debug)]
struct PlainLines {
    what: String,
    every: f64,
    start: Instant,
    last: Mutex<f64>,
}

/// A progress count with a message, drawn as a bar where that is possible.
#[derive(Clone)]
pub struct Progress {
    #[cfg(feature = "bars")]
    bar: indicatif::ProgressBar,
    #[cfg(not(feature = "bars"))]
    counts: std::sync::Arc<std::sync::atomic::AtomicU64>,
    #[cfg(not(feature = "bars"))]
    len: std::sync::Arc<std::sync::atomic::AtomicU64>,
    /// Plain lines when no bar is drawn (only for [`progress_bar`]).
    plain: Option<Arc<PlainLines>>,
}

impl Progress {
    /// A bar of `len` steps labelled `what` (drawn only on a terminal).
    pub fn new(len: u64, what: &str) -> Self {
        #[cfg(feature = "bars")]
        {
            let bar = indicatif::ProgressBar::new(len);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{msg} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}",
                )
                .expect("valid template")
                .progress_chars("=> "),
            );
            bar.set_message(what.to_string());
            Self { bar, plain: None }
        }
        #[cfg(not(feature = "bars"))]
        {
            let _ = what;
            Self {
                counts: Default::default(),
                len: std::sync::Arc::new(len.into()),
                plain: None,
            }
        }
    }

    /// A progress that draws nothing.
    pub fn hidden() -> Self {
        #[cfg(feature = "bars")]
        {
            Self {
                bar: indicatif::ProgressBar::hidden(),
                plain: None,
            }
        }
        #[cfg(not(feature = "bars"))]
        {
            Self::new(0, "")
        }
    }

    /// Whether no bar is drawn (stderr is not a terminal, or no `cli` feature).
    pub fn is_hidden(&self) -> bool {
        #[cfg(feature = "bars")]
        {
            self.bar.is_hidden()
        }
        #[cfg(not(feature = "bars"))]
        {
            true
        }
    }

    /// Advances by `n` steps (and prints a plain line when one is due).
    pub fn inc(&self, n: u64) {
        #[cfg(feature = "bars")]
        self.bar.inc(n);
        #[cfg(not(feature = "bars"))]
        self.counts
            .fetch_add(n, std::sync::atomic::Ordering::Relaxed);
        if let Some(plain) = &self.plain {
            let now = plain.start.elapsed().as_secs_f64();
            let mut last = plain.last.lock().unwrap_or_else(|e| e.into_inner());
            if now - *last >= plain.every {
                *last = now;
                log::info!(
                    "{}: {}/{} after {:.0} s",
                    plain.what,
                    self.position(),
                    self.length(),
                    now
                );
            }
        }
    }

    /// Sets the steps in all (a run whose length is known only as it goes: one that trains
    /// for a time).
    pub fn set_length(&self, len: u64) {
        #[cfg(feature = "bars")]
        self.bar.set_length(len);
        #[cfg(not(feature = "bars"))]
        self.len.store(len, std::sync::atomic::Ordering::Relaxed);
    }

    /// Steps done so far.
    pub fn position(&self) -> u64 {
        #[cfg(feature = "bars")]
        {
            self.bar.position()
        }
        #[cfg(not(feature = "bars"))]
        {
            self.counts.load(std::sync::atomic::Ordering::Relaxed)
        }
    }

    /// Steps in all.
    pub fn length(&self) -> u64 {
        #[cfg(feature = "bars")]
        {
            self.bar.length().unwrap_or(0)
        }
        #[cfg(not(feature = "bars"))]
        {
            self.len.load(std::sync::atomic::Ordering::Relaxed)
        }
    }

    /// Sets the bar's message (nothing when hidden).
    pub fn set_message(&self, message: String) {
        #[cfg(feature = "bars")]
        self.bar.set_message(message);
        #[cfg(not(feature = "bars"))]
        let _ = message;
    }

    /// Prints `message` as a line above the bar, or on stderr when the bar is hidden (indicatif
    /// drops the lines of a hidden bar).
    pub fn println(&self, message: &str) {
        #[cfg(feature = "bars")]
        if !self.bar.is_hidden() {
            self.bar.println(message);
            return;
        }
        log::info!("{message}");
    }

    /// Removes the bar.
    pub fn finish_and_clear(&self) {
        #[cfg(feature = "bars")]
        self.bar.finish_and_clear();
    }
}

/// A progress bar on stderr, drawn on a terminal; elsewhere a plain line every
/// [`plain_line_seconds`].
pub fn progress_bar(len: u64, what: &str) -> Progress {
    let mut progress = Progress::new(len, what);
    if progress.is_hidden() {
        progress.plain = Some(Arc::new(PlainLines {
            what: what.to_string(),
            every: plain_line_seconds(),
            start: Instant::now(),
            last: Mutex::new(0.0),
        }));
    }
    progress
}
