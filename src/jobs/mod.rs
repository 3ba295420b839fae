//! The use cases, a request in and a typed outcome out: estimating ([`estimate`]) and
//! acquiring ([`acquire`]) a sample. Every application (the command
//! line, the Python package, the lab's evaluation and the production line) runs the
//! estimator through [`estimate`], so whatever the estimate learns to do reaches all of
//! them; and it is here that an estimate's output folder is opened and its summary written.
//!
//! Imports point one way: `jobs` uses the estimator, the sources and the files below it;
//! nothing below it imports `jobs`. A job tells its caller how it is going through an
//! [`Observer`], not through closures threaded through its callees.

pub mod acquire;
pub mod estimate;

pub use estimate::{EstimateError, EstimateRequest, GivenIndex, Outcome, Settings};

/// What a job tells its caller as it goes. Every method does nothing unless implemented.
pub trait Observer: Sync {
    /// The job starts streaming `rows` rows (image rows x bands x angles) of `label`.
    fn begin(&self, label: &str, rows: u64) {
        let _ = (label, rows);
    }
    /// `n` more rows are through the estimator.
    fn rows(&self, n: u64) {
        let _ = n;
    }
    /// The sweep is through the estimator.
    fn end(&self) {}
    /// A problem with the input that does not stop the job (an unknown key, say).
    fn warning(&self, message: &str) {
        let _ = message;
    }
}

/// An observer that ignores everything.
pub struct Quiet;

impl Observer for Quiet {}
