//! Wire codecs of the rig's devices: pure functions over buffers the caller owns, no I/O,
//! no clock, no allocation. The host drivers and the firmware simulator both speak through
//! these, so the two sides cannot drift apart.
//!
//! - [`zaber`]: Zaber ASCII (rotation stage): commands, replies, the LRC checksum.
//! - [`kurios`]: Thorlabs Kurios LCTF: `KEY=value` commands, queries and the `>` prompt.
//! - [`sxwheel`]: Starlight Xpress filter wheel HID reports.
//! - [`fscl`]: the camera link's framing (`FSCL`), CRC-32/IEEE, leader/row/trailer payloads.

pub mod fscl;
pub mod kurios;
pub mod sxwheel;
pub mod zaber;
