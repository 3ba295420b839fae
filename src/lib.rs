//! filmscope (placeholder doc, rewritten later).
#![cfg_attr(not(feature = "std"), no_std)]

pub use filmscope_core::*;

#[cfg(feature = "std")]
pub mod baseline;
#[cfg(feature = "std")]
pub mod cli;
#[cfg(feature = "std")]
pub mod estimate;
#[cfg(feature = "std")]
pub mod eval;
#[cfg(feature = "std")]
pub mod export;
#[cfg(feature = "std")]
pub mod io;
#[cfg(feature = "std")]
pub mod pipeline;
#[cfg(feature = "std")]
pub mod simulate;
#[cfg(feature = "std")]
pub mod sweep;
