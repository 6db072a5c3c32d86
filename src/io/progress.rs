//! Progress on stderr: an indicatif bar on a terminal (with the `cli` feature); without the
//! feature, or off a terminal, no bar is drawn and [`Progress::println`] writes plain lines.

/// A progress count with a message, drawn as a bar where that is possible.
#[derive(Clone)]
pub struct Progress {
    #[cfg(feature = "cli")]
    bar: indicatif::ProgressBar,
    #[cfg(not(feature = "cli"))]
    counts: std::sync::Arc<std::sync::atomic::AtomicU64>,
    #[cfg(not(feature = "cli"))]
    len: u64,
}

impl Progress {
    /// A bar of `len` steps labelled `what` (drawn only on a terminal).
    pub fn new(len: u64, what: &str) -> Self {
        #[cfg(feature = "cli")]
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
            Self { bar }
        }
        #[cfg(not(feature = "cli"))]
        {
            let _ = what;
            Self {
                counts: Default::default(),
                len,
            }
        }
    }

    /// A progress that draws nothing.
    pub fn hidden() -> Self {
        #[cfg(feature = "cli")]
        {
            Self {
                bar: indicatif::ProgressBar::hidden(),
            }
        }
        #[cfg(not(feature = "cli"))]
        {
            Self::new(0, "")
        }
    }

    /// Whether no bar is drawn (stderr is not a terminal, or no `cli` feature).
    pub fn is_hidden(&self) -> bool {
        #[cfg(feature = "cli")]
        {
            self.bar.is_hidden()
        }
        #[cfg(not(feature = "cli"))]
        {
            true
        }
    }

    /// Advances by `n` steps.
    pub fn inc(&self, n: u64) {
        #[cfg(feature = "cli")]
        self.bar.inc(n);
        #[cfg(not(feature = "cli"))]
        self.counts
            .fetch_add(n, std::sync::atomic::Ordering::Relaxed);
    }

    /// Steps done so far.
    pub fn position(&self) -> u64 {
        #[cfg(feature = "cli")]
        {
            self.bar.position()
        }
        #[cfg(not(feature = "cli"))]
        {
            self.counts.load(std::sync::atomic::Ordering::Relaxed)
        }
    }

    /// Steps in all.
    pub fn length(&self) -> u64 {
        #[cfg(feature = "cli")]
        {
            self.bar.length().unwrap_or(0)
        }
        #[cfg(not(feature = "cli"))]
        {
            self.len
        }
    }

    /// Sets the bar's message (nothing when hidden).
    pub fn set_message(&self, message: String) {
        #[cfg(feature = "cli")]
        self.bar.set_message(message);
        #[cfg(not(feature = "cli"))]
        let _ = message;
    }

    /// Prints `message` as a line above the bar, or on stderr when the bar is hidden (indicatif
    /// drops the lines of a hidden bar).
    pub fn println(&self, message: &str) {
        #[cfg(feature = "cli")]
        if !self.bar.is_hidden() {
            self.bar.println(message);
            return;
        }
        crate::core::term::note(message);
    }

    /// Removes the bar.
    pub fn finish_and_clear(&self) {
        #[cfg(feature = "cli")]
        self.bar.finish_and_clear();
    }
}

/// A progress bar on stderr (drawn only on a terminal).
pub fn progress_bar(len: u64, what: &str) -> Progress {
    Progress::new(len, what)
}
