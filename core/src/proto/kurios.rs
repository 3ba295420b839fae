//! Thorlabs Kurios LCTF: `KEY=value` commands and `KEY?` queries ended by CR; every reply,
//! sets included, ends with the prompt `>`. An unknown command answers `CMD_NOT_DEFINED`.
//!
//! Unconfirmed details (kept configurable or tolerant here): the out-of-range reply text
//! (any line holding `ERROR`, `INVALID` or `NOT_DEFINED` is taken as a refusal) and the
//! status reply form (`ST=2` or a bare `2`).

use core::fmt::Write;

/// The prompt that ends every reply.
pub const PROMPT: u8 = b'>';

/// Longest command line this codec writes.
pub const MAX_COMMAND: usize = 32;

/// A command line, CR included.
pub type CommandLine = heapless::String<MAX_COMMAND>;

/// `WL=550.000\r`: tune to `lambda_nm` (three decimals, as the filter takes them).
pub fn set_wavelength(lambda_nm: f64) -> Option<CommandLine> {
    let mut s = CommandLine::new();
    write!(s, "WL={lambda_nm:.3}\r").ok()?;
    Some(s)
}

/// `KEY=value\r` with an integer value.
pub fn set(key: &str, value: u32) -> Option<CommandLine> {
    let mut s = CommandLine::new();
    write!(s, "{key}={value}\r").ok()?;
    Some(s)
}

/// `KEY?\r` (a query).
pub fn query(key: &str) -> Option<CommandLine> {
    let mut s = CommandLine::new();
    write!(s, "{key}?\r").ok()?;
    Some(s)
}

/// Whether a reply line is a refusal (unknown command, bad argument, error text).
pub fn is_refusal(line: &str) -> bool {
    let upper = |needle: &str| {
        line.as_bytes()
            .windows(needle.len())
            .any(|w| w.eq_ignore_ascii_case(needle.as_bytes()))
    };
    upper("NOT_DEFINED") || upper("INVALID") || upper("ERROR")
}

/// The value of `KEY=value` in `line` (case-insensitive key), if the line holds that key.
pub fn value<'a>(line: &'a str, key: &str) -> Option<&'a str> {
    let line = line.trim_matches(|c: char| c == '\r' || c == '\n' || c == ' ' || c == '>');
    let (k, v) = line.split_once('=')?;
    k.trim().eq_ignore_ascii_case(key).then_some(v.trim())
}

/// A number, either `KEY=number` or a bare number.
pub fn number(line: &str, key: &str) -> Option<f64> {
    let bare = line.trim_matches(|c: char| c == '\r' || c == '\n' || c == ' ' || c == '>');
    value(line, key).unwrap_or(bare).parse().ok()
}

/// The `OH?` reply decoded: the head's range and the bandwidth modes it offers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Head {
    /// 1 visible, 2 near infrared.
    pub range: u8,
    /// Bandwidth-mode bitmask (1 black, 2 wide, 4 medium, 8 narrow, 16 super-narrow).
    pub modes: u8,
}

/// Decodes `OH=n` (high byte range, low byte bandwidth modes).
pub fn head(line: &str) -> Option<Head> {
    let n = number(line, "OH")?;
    if !(0.0..=65535.0).contains(&n) {
        return None;
    }
    let n = n as u32;
    Some(Head {
        range: (n >> 8) as u8,
        modes: (n & 0xFF) as u8,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_and_replies() {
        assert_eq!(set_wavelength(550.0).as_deref(), Some("WL=550.000\r"));
        assert_eq!(set("BW", 8).as_deref(), Some("BW=8\r"));
        assert_eq!(query("SP").as_deref(), Some("SP?\r"));
        assert_eq!(number("WL=550.000\r", "WL"), Some(550.0));
        assert_eq!(number("WLmax=730.000", "WLmax"), Some(730.0));
        assert_eq!(number("ST=2", "ST"), Some(2.0));
        assert_eq!(number("2", "ST"), Some(2.0));
        assert_eq!(number("garbage", "ST"), None);
        assert_eq!(
            head("OH=271"),
            Some(Head {
                range: 1,
                modes: 15
            })
        );
        assert!(is_refusal("CMD_NOT_DEFINED"));
        assert!(is_refusal("Command error CMD_ARG_INVALID"));
        assert!(!is_refusal("WL=550.000"));
    }
}
