//! Starlight Xpress filter wheel (USB HID, VID 0x1278, PID 0x0920): 2-byte reports, report
//! id 0 prepended on write.
//!
//! `[0, 0]` asks for `[position (1-based, 0 while moving), filter count]`; `[0, 1]` asks the
//! wheel to count its filters (poll `[0, 0]` until byte 0 is non-zero); `[n + 129, 0]` turns
//! to 0-based slot `n`.

/// USB vendor id.
pub const VENDOR_ID: u16 = 0x1278;
/// USB product id.
pub const PRODUCT_ID: u16 = 0x0920;

/// The report asking for position and count (report id 0 first).
pub const QUERY: [u8; 3] = [0, 0, 0];
/// The report asking the wheel to count its filters.
pub const COUNT: [u8; 3] = [0, 0, 1];

/// The report turning the wheel to 0-based `slot`; `None` for a slot no wheel has.
pub fn select(slot: u8) -> Option<[u8; 3]> {
    let code = slot.checked_add(129)?;
    Some([0, code, 0])
}

/// Which slot a command report (without its report id) asks for, for the firmware
/// simulator: `Some(Some(n))` a move to slot n, `Some(None)` a query or count.
pub fn decode_command(report: [u8; 2]) -> Option<Option<u8>> {
    match report {
        [0, 0] | [0, 1] => Some(None),
        [c, 0] if c >= 129 => Some(Some(c - 129)),
        _ => None,
    }
}

/// A status report decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Status {
    /// 0-based slot, `None` while turning (or counting).
    pub slot: Option<u8>,
    /// Number of filters.
    pub count: u8,
}

/// Decodes a status report.
pub fn status(report: [u8; 2]) -> Status {
    Status {
        slot: report[0].checked_sub(1),
        count: report[1],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reports() {
        assert_eq!(select(0), Some([0, 129, 0]));
        assert_eq!(select(4), Some([0, 133, 0]));
        assert_eq!(select(200), None);
        assert_eq!(decode_command([133, 0]), Some(Some(4)));
        assert_eq!(decode_command([0, 1]), Some(None));
        assert_eq!(decode_command([7, 7]), None);
        assert_eq!(
            status([3, 5]),
            Status {
                slot: Some(2),
                count: 5
            }
        );
        assert_eq!(status([0, 5]).slot, None);
    }
}
