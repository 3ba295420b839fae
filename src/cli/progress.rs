//! Progress bars, only on a terminal.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressStyle};

/// A bar of `total` rows titled `what`, hidden when stderr is not a terminal or `--quiet`.
pub fn rows_bar(total: u64, what: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() || log::max_level() < log::LevelFilter::Info {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total);
    let style =
        ProgressStyle::with_template("{msg:>24} [{bar:40}] {percent:>3}% {elapsed_precise}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> ");
    bar.set_style(style);
    bar.set_message(what.to_owned());
    bar
}

/// A job's observer for the terminal: a bar of the rows streamed (when stderr is one) and
/// its warnings on stderr.
pub struct Progress(ProgressBar);

impl Progress {
    /// A bar not yet started.
    pub fn new() -> Self {
        Self(rows_bar(0, ""))
    }
}

impl filmscope::jobs::Observer for Progress {
    fn begin(&self, label: &str, rows: u64) {
        self.0.reset();
        self.0.set_length(rows);
        self.0.set_message(label.to_owned());
    }

    fn rows(&self, n: u64) {
        self.0.inc(n);
    }

    fn end(&self) {
        self.0.finish_and_clear();
    }

    fn warning(&self, message: &str) {
        self.0.suspend(|| log::warn!("{message}"));
    }
}
