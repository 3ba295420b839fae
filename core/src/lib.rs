//! filmscope's no_std core (placeholder doc, rewritten later).
#![cfg_attr(not(feature = "std"), no_std)]

pub mod calibrate;
pub mod colour;
pub mod optics;
pub mod solve;
pub mod track;
