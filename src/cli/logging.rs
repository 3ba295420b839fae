//! Messages on standard error through the `log` facade, by level: `--quiet` errors only;
//! by default notes and warnings too; `-v` the steps of a job; `-vv` everything.

use log::{Level, LevelFilter, Log, Metadata, Record};

/// The logger: one line per message on standard error. Errors and warnings carry the
/// program's name; notes and the rest are printed as they are written.
struct Stderr;

impl Log for Stderr {
    fn enabled(&self, metadata: &Metadata) -> bool {
        metadata.level() <= log::max_level()
    }

    fn log(&self, record: &Record) {
        if !self.enabled(record.metadata()) {
            return;
        }
        match record.level() {
            Level::Error => eprintln!("filmscope: {}", record.args()),
            Level::Warn => eprintln!("filmscope: warning: {}", record.args()),
            Level::Info => eprintln!("{}", record.args()),
            Level::Debug | Level::Trace => eprintln!("filmscope: {}", record.args()),
        }
    }

    fn flush(&self) {}
}

/// Sets the level from `--quiet` and the count of `-v`.
pub fn init(quiet: bool, verbose: u8) {
    let _ = log::set_logger(&Stderr);
    log::set_max_level(match (quiet, verbose) {
        (true, _) => LevelFilter::Error,
        (false, 0) => LevelFilter::Info,
        (false, 1) => LevelFilter::Debug,
        (false, _) => LevelFilter::Trace,
    });
}
