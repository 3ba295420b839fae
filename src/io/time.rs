//! Wall-clock times as the line and the rig write them: ISO 8601 UTC and sample ids.

use std::time::{SystemTime, UNIX_EPOCH};

use time::OffsetDateTime;

/// `t` in UTC (the epoch for a time before it).
fn utc(t: SystemTime) -> OffsetDateTime {
    let d = t.duration_since(UNIX_EPOCH).unwrap_or_default();
    OffsetDateTime::from_unix_timestamp_nanos(d.as_nanos() as i128)
        .unwrap_or(OffsetDateTime::UNIX_EPOCH)
}

/// ISO 8601 UTC with milliseconds: `2026-11-25T22:30:00.123Z`.
pub fn utc_iso(t: SystemTime) -> String {
    let u = utc(t);
    let (y, mo, d) = (u.year(), u8::from(u.month()), u.day());
    let (h, mi, s, ms) = (u.hour(), u.minute(), u.second(), u.millisecond());
    format!("{y:04}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}.{ms:03}Z")
}

/// The UTC date, `2026-11-25` (the dated bench files' names).
pub fn utc_date(t: SystemTime) -> String {
    let u = utc(t);
    format!("{:04}-{:02}-{:02}", u.year(), u8::from(u.month()), u.day())
}

/// A sample id: the counter (6 digits at least) and the UTC time, `S000042-20261125T223000Z`.
/// Ids sort as the counter does.
pub fn sample_id(counter: u64, t: SystemTime) -> String {
    let u = utc(t);
    let (y, mo, d) = (u.year(), u8::from(u.month()), u.day());
    let (h, mi, s) = (u.hour(), u.minute(), u.second());
    format!("S{counter:06}-{y:04}{mo:02}{d:02}T{h:02}{mi:02}{s:02}Z")
}

/// The counter of a sample id (or folder name), if it is one.
pub fn counter_of(id: &str) -> Option<u64> {
    id.strip_prefix('S')?.split('-').next()?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn times_and_ids() {
        let t = UNIX_EPOCH + Duration::from_millis(1_795_905_000_123);
        assert_eq!(utc_iso(t), "2026-11-28T22:30:00.123Z");
        assert_eq!(utc_iso(UNIX_EPOCH), "1970-01-01T00:00:00.000Z");
        assert_eq!(
            utc_iso(UNIX_EPOCH + Duration::from_secs(951_782_400)),
            "2000-02-29T00:00:00.000Z"
        );
        let id = sample_id(42, t);
        assert_eq!(id, "S000042-20261128T223000Z");
        assert_eq!(counter_of(&id), Some(42));
        assert_eq!(counter_of("S1234567-x"), Some(1_234_567));
        assert_eq!(counter_of(".tmp-S1"), None);
    }

    #[test]
    fn utc_dates() {
        assert_eq!(utc_date(UNIX_EPOCH), "1970-01-01");
        // 2000-02-29 12:00 UTC and 2026-11-26 04:18 UTC.
        assert_eq!(
            utc_date(UNIX_EPOCH + Duration::from_secs(951_825_600)),
            "2000-02-29"
        );
        assert_eq!(
            utc_date(UNIX_EPOCH + Duration::from_secs(1_795_666_680)),
            "2026-11-26"
        );
    }
}
