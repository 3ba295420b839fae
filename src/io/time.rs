//! Wall-clock times as the line and the rig write them: ISO 8601 UTC and sample ids.

use std::time::{SystemTime, UNIX_EPOCH};

/// Civil date (year, month, day) of a day count since 1970-01-01 (proleptic Gregorian).
fn civil(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d)
}

/// UTC parts of a time: (year, month, day, hour, minute, second, millisecond).
fn parts(t: SystemTime) -> (i64, u32, u32, u32, u32, u32, u32) {
    let d = t.duration_since(UNIX_EPOCH).unwrap_or_default();
    let secs = d.as_secs() as i64;
    let (y, mo, da) = civil(secs.div_euclid(86_400));
    let s = secs.rem_euclid(86_400) as u32;
    (y, mo, da, s / 3600, s / 60 % 60, s % 60, d.subsec_millis())
}

/// ISO 8601 UTC with milliseconds: `2026-11-25T22:30:00.123Z`.
pub fn utc_iso(t: SystemTime) -> String {
    let (y, mo, d, h, mi, s, ms) = parts(t);
    format!("{y:04}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}.{ms:03}Z")
}

/// A sample id: the counter (6 digits at least) and the UTC time, `S000042-20261125T223000Z`.
/// Ids sort as the counter does.
pub fn sample_id(counter: u64, t: SystemTime) -> String {
    let (y, mo, d, h, mi, s, _) = parts(t);
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
}
