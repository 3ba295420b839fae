//! filmscope (placeholder doc, rewritten later).
#![cfg_attr(not(feature = "std"), no_std)]

pub use filmscope_core::*;

#[cfg(feature = "std")]
pub mod baseline;
#[cfg(feature = "std")]
pub mod io;
#[cfg(feature = "std")]
pub mod sweep;
