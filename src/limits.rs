//! The bounds every numeric input is checked against before any work or device motion, and
//! the memory a run needs against what the machine has.
//!
//! Each check returns one line naming the key and its value (the caller adds the file):
//! `sample.ambient_index = 1e9: expected a finite index in [1, 3]`. The bounds are physical
//! (refractive indices of transparent films and media, visible to near-infrared bands) and
//! keep the search, the brute-force grid and the sweep finite in time and memory.

use std::path::Path;

/// Lowest refractive index accepted for a film, substrate or ambient medium.
pub const MIN_INDEX: f64 = 1.0;
/// Highest refractive index accepted for a film or substrate.
pub const MAX_INDEX: f64 = 6.0;
/// Highest ambient index accepted (air, water, immersion oils lie far below).
pub const MAX_AMBIENT_INDEX: f64 = 3.0;
/// Thickest film the search may look for, nm (fringes of a thicker film wash out under any
/// passband the rig can tune).
pub const MAX_THICKNESS_NM: f64 = 50_000.0;
/// Shortest band centre accepted, nm.
pub const MIN_WAVELENGTH_NM: f64 = 200.0;
/// Longest band centre accepted, nm.
pub const MAX_WAVELENGTH_NM: f64 = 3_000.0;
/// Widest passband accepted, nm.
pub const MAX_FWHM_NM: f64 = 500.0;
/// Most incidence angles in one sweep.
pub const MAX_ANGLES: usize = 256;
/// Finest brute-force thickness step, nm.
pub const MIN_BRUTE_THICKNESS_STEP_NM: f64 = 0.1;
/// Coarsest brute-force thickness step, nm.
pub const MAX_BRUTE_THICKNESS_STEP_NM: f64 = 1_000.0;
/// Most brute-force index values.
pub const MAX_BRUTE_INDEX_STEPS: usize = 2_000;
/// Most worker threads.
pub const MAX_WORKERS: usize = 256;
/// Largest pipeline channel capacity, messages.
pub const MAX_CHANNEL_CAPACITY: usize = 1 << 16;

/// An input outside its bounds, or a run that would not fit in memory: one line each,
/// naming the key and its value (the caller adds the file).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LimitError {
    /// A value outside its bounds: `key = value: expected what`.
    #[error("{key} = {value}: expected {expected}")]
    OutOfRange {
        /// The key or option, as the user wrote it (`search.index_range`, `--workers`).
        key: String,
        /// The value given, as written back.
        value: String,
        /// What is accepted.
        expected: String,
    },
    /// The ambient medium denser than the substrate.
    #[error("{ambient_key} = {ambient:?} is above {substrate_key} = {substrate:?}: the light must come from the lower-index side")]
    AmbientAboveSubstrate {
        /// The ambient index's key.
        ambient_key: String,
        /// The ambient index.
        ambient: f64,
        /// The substrate index's key.
        substrate_key: String,
        /// The substrate index.
        substrate: f64,
    },
    /// Band widths whose count is not the bands'.
    #[error("{key}: {given} values for {bands} bands")]
    WidthCount {
        /// The widths' key.
        key: String,
        /// Widths given.
        given: usize,
        /// Bands.
        bands: usize,
    },
    /// A run needing more memory than it may take.
    #[error("{what}: needs about {} of memory, more than {whose} of {}", gib(*needed), gib(*limit))]
    Memory {
        /// What the figure is for.
        what: String,
        /// Bytes needed.
        needed: u64,
        /// Bytes it may take.
        limit: u64,
        /// Whose limit: the `--max-memory` budget or the memory available.
        whose: &'static str,
    },
}

/// Callers whose own errors are still one line of text take a limit's line as it is.
impl From<LimitError> for String {
    fn from(e: LimitError) -> Self {
        e.to_string()
    }
}

/// `key = value: expected what`.
fn bad(key: &str, value: impl std::fmt::Display, expected: &str) -> LimitError {
    LimitError::OutOfRange {
        key: key.to_owned(),
        value: value.to_string(),
        expected: expected.to_owned(),
    }
}

/// A film refractive index range `[low, high]` inside `[MIN_INDEX, MAX_INDEX]`, low below
/// high.
pub fn check_index_range(key: &str, [lo, hi]: [f64; 2]) -> Result<(), LimitError> {
    if !(lo.is_finite() && hi.is_finite() && MIN_INDEX <= lo && lo < hi && hi <= MAX_INDEX) {
        return Err(bad(
            key,
            format!("[{lo:?}, {hi:?}]"),
            &format!("finite {MIN_INDEX} <= low < high <= {MAX_INDEX}"),
        ));
    }
    Ok(())
}

/// A thickness range `[low, high]` in nm, `0 < low < high <= MAX_THICKNESS_NM`.
pub fn check_thickness_range(key: &str, [lo, hi]: [f64; 2]) -> Result<(), LimitError> {
    if !(lo.is_finite() && hi.is_finite() && 0.0 < lo && lo < hi && hi <= MAX_THICKNESS_NM) {
        return Err(bad(
            key,
            format!("[{lo:?}, {hi:?}]"),
            &format!("finite 0 < low < high <= {MAX_THICKNESS_NM} nm"),
        ));
    }
    Ok(())
}

/// The sample's ambient and substrate indices: each finite and physical, the ambient not
/// above the substrate.
pub fn check_sample(
    ambient_key: &str,
    ambient: f64,
    substrate_key: &str,
    substrate: f64,
) -> Result<(), LimitError> {
    if !(substrate.is_finite() && (MIN_INDEX..=MAX_INDEX).contains(&substrate)) {
        return Err(bad(
            substrate_key,
            format!("{substrate:?}"),
            &format!("a finite index in [{MIN_INDEX}, {MAX_INDEX}]"),
        ));
    }
    if !(ambient.is_finite() && (MIN_INDEX..=MAX_AMBIENT_INDEX).contains(&ambient)) {
        return Err(bad(
            ambient_key,
            format!("{ambient:?}"),
            &format!("a finite index in [{MIN_INDEX}, {MAX_AMBIENT_INDEX}]"),
        ));
    }
    if ambient > substrate {
        return Err(LimitError::AmbientAboveSubstrate {
            ambient_key: ambient_key.to_owned(),
            ambient,
            substrate_key: substrate_key.to_owned(),
            substrate,
        });
    }
    Ok(())
}

/// Band centres: finite, in `[MIN_WAVELENGTH_NM, MAX_WAVELENGTH_NM]`, strictly increasing;
/// band widths (if given, one per band): finite, in `(0, MAX_FWHM_NM]`.
pub fn check_bands(
    key: &str,
    bands_nm: &[f64],
    fwhm_key: &str,
    fwhm_nm: Option<&[f64]>,
) -> Result<(), LimitError> {
    for (i, &w) in bands_nm.iter().enumerate() {
        if !(w.is_finite() && (MIN_WAVELENGTH_NM..=MAX_WAVELENGTH_NM).contains(&w)) {
            return Err(bad(
                &format!("{key}[{i}]"),
                format!("{w:?}"),
                &format!("a wavelength in [{MIN_WAVELENGTH_NM}, {MAX_WAVELENGTH_NM}] nm"),
            ));
        }
        if i > 0 && w <= bands_nm[i - 1] {
            return Err(bad(
                &format!("{key}[{i}]"),
                format!("{w:?}"),
                &format!(
                    "wavelengths in increasing order (the band before is {} nm)",
                    bands_nm[i - 1]
                ),
            ));
        }
    }
    if let Some(f) = fwhm_nm {
        if f.len() != bands_nm.len() {
            return Err(LimitError::WidthCount {
                key: fwhm_key.to_owned(),
                given: f.len(),
                bands: bands_nm.len(),
            });
        }
        for (i, &w) in f.iter().enumerate() {
            if !(w.is_finite() && w > 0.0 && w <= MAX_FWHM_NM) {
                return Err(bad(
                    &format!("{fwhm_key}[{i}]"),
                    format!("{w:?}"),
                    &format!("a passband width in (0, {MAX_FWHM_NM}] nm"),
                ));
            }
        }
    }
    Ok(())
}

/// An angle count in `[1, MAX_ANGLES]`.
pub fn check_angle_count(key: &str, n: usize) -> Result<(), LimitError> {
    if !(1..=MAX_ANGLES).contains(&n) {
        return Err(bad(
            key,
            format!("{n} angles"),
            &format!("1 to {MAX_ANGLES} angles"),
        ));
    }
    Ok(())
}

/// The command line's numeric options.
pub fn check_cli(
    workers: usize,
    channel_capacity: usize,
    index_pixels: usize,
    brute_index_steps: usize,
    brute_thickness_step_nm: f64,
) -> Result<(), LimitError> {
    if !(1..=MAX_WORKERS).contains(&workers) {
        return Err(bad("--workers", workers, &format!("1 to {MAX_WORKERS}")));
    }
    if !(1..=MAX_CHANNEL_CAPACITY).contains(&channel_capacity) {
        return Err(bad(
            "--channel-capacity",
            channel_capacity,
            &format!("1 to {MAX_CHANNEL_CAPACITY} messages"),
        ));
    }
    if index_pixels == 0 {
        return Err(bad("--index-pixels", 0, "at least 1 pixel"));
    }
    if brute_index_steps > MAX_BRUTE_INDEX_STEPS {
        return Err(bad(
            "--brute-index-steps",
            brute_index_steps,
            &format!("0 (a 0.01 step) to {MAX_BRUTE_INDEX_STEPS}"),
        ));
    }
    let s = brute_thickness_step_nm;
    if !(s.is_finite() && (MIN_BRUTE_THICKNESS_STEP_NM..=MAX_BRUTE_THICKNESS_STEP_NM).contains(&s))
    {
        return Err(bad(
            "--brute-thickness-step",
            format!("{s:?}"),
            &format!("a step in [{MIN_BRUTE_THICKNESS_STEP_NM}, {MAX_BRUTE_THICKNESS_STEP_NM}] nm"),
        ));
    }
    Ok(())
}

/// Bytes a streaming run keeps per pixel, every allocation counted generously: the
/// solver's state (about 105 B), the shared index's sums, the output maps, one held row
/// block per band and the PNG preview.
pub const RUN_BYTES_PER_PIXEL: u64 = 1024;
/// Bytes a run needs beyond its pixels (tables, threads, buffers).
pub const RUN_FIXED_BYTES: u64 = 64 << 20;

/// The memory a run over `pixels` pixels, `bands` bands and `angles` angles needs, bytes:
/// the streaming state per pixel, plus the whole cube in `f32` when `whole_cube` (the paper
/// and brute-force methods hold every sample).
pub fn run_bytes(pixels: u64, bands: u64, angles: u64, whole_cube: bool) -> u64 {
    let per_pixel = if whole_cube {
        RUN_BYTES_PER_PIXEL.saturating_add(bands.saturating_mul(angles).saturating_mul(4))
    } else {
        RUN_BYTES_PER_PIXEL
    };
    pixels
        .saturating_mul(per_pixel)
        .saturating_add(RUN_FIXED_BYTES)
}

/// `MemAvailable` of `/proc/meminfo`, bytes (`None` where there is no such file).
pub fn available_memory() -> Option<u64> {
    let text = read_small(Path::new("/proc/meminfo"), 1 << 16).ok()?;
    parse_meminfo(&text)
}

fn parse_meminfo(text: &str) -> Option<u64> {
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024))
}

/// Parses a memory budget: bytes, or a number with `K`, `M`, `G` or `T` (powers of 1024,
/// `B`/`iB` suffixes accepted).
pub fn parse_bytes(text: &str) -> Result<u64, LimitError> {
    let t = text.trim();
    let t = t
        .strip_suffix("iB")
        .or_else(|| t.strip_suffix('B'))
        .unwrap_or(t);
    let (num, shift) = match t.chars().last() {
        Some('K' | 'k') => (&t[..t.len() - 1], 1),
        Some('M' | 'm') => (&t[..t.len() - 1], 2),
        Some('G' | 'g') => (&t[..t.len() - 1], 3),
        Some('T' | 't') => (&t[..t.len() - 1], 4),
        _ => (t, 0),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| bad("--max-memory", text, "bytes, or a number with K, M, G or T"))?;
    let bytes = v * 1024f64.powi(shift);
    if !(1.0..1.8e19).contains(&bytes) {
        return Err(bad("--max-memory", text, "a positive size below 16 EiB"));
    }
    Ok(bytes as u64)
}

fn gib(bytes: u64) -> String {
    let b = bytes as f64;
    if b >= f64::from(1u32 << 30) {
        format!("{:.1} GiB", b / f64::from(1u32 << 30))
    } else {
        format!("{:.1} MiB", b / f64::from(1u32 << 20))
    }
}

/// Refuses a run needing `needed` bytes when it exceeds `budget` (the `--max-memory`
/// given) or, without one, the machine's available memory. `what` says what the figure is
/// for (`thickness_nm.hdr: 100000 x 100000 px, 16 bands, 5 angles`).
pub fn check_memory(what: &str, needed: u64, budget: Option<u64>) -> Result<(), LimitError> {
    let (limit, whose) = match budget {
        Some(b) => (Some(b), "the --max-memory budget"),
        None => (available_memory(), "the memory available (MemAvailable)"),
    };
    match limit {
        Some(limit) if needed > limit => Err(LimitError::Memory {
            what: what.to_owned(),
            needed,
            limit,
            whose,
        }),
        _ => Ok(()),
    }
}

/// Reads a small regular file: refuses FIFOs, devices and directories (which would block or
/// never end) and files over `max_bytes`; the text must be UTF-8.
pub fn read_small(path: &Path, max_bytes: u64) -> std::io::Result<String> {
    use std::io::Read as _;
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file (a FIFO, device or directory)",
        ));
    }
    if meta.len() > max_bytes {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("file is over {max_bytes} bytes"),
        ));
    }
    let file = std::fs::File::open(path)?;
    let mut bytes = Vec::new();
    file.take(max_bytes + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("file is over {max_bytes} bytes"),
        ));
    }
    String::from_utf8(bytes)
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text"))
}

/// `text` with control characters (escape sequences, NUL, bells, line ends) written as
/// escapes (`\u{1b}`, `\0`, `\n`), so device text cannot drive a terminal or split a log
/// line. Everything else is kept, so escaping twice changes nothing more.
pub fn printable(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        if c.is_control() {
            out.extend(c.escape_debug());
        } else {
            out.push(c);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budgets_parse_and_memory_is_compared() {
        assert_eq!(parse_bytes("512M"), Ok(512 << 20));
        assert_eq!(parse_bytes("2GiB"), Ok(2 << 30));
        assert_eq!(parse_bytes("1000"), Ok(1000));
        assert!(parse_bytes("-1G").is_err() && parse_bytes("lots").is_err());
        assert_eq!(
            parse_meminfo("MemTotal: 100 kB\nMemAvailable:    2048 kB\n"),
            Some(2 << 20)
        );
        assert!(check_memory("x", 2 << 30, Some(1 << 30)).is_err());
        assert!(check_memory("x", 1 << 20, Some(1 << 30)).is_ok());
    }

    #[test]
    fn device_text_is_escaped_once() {
        let s = printable("ok\u{1b}[2J\0bell\u{7}");
        assert_eq!(s, "ok\\u{1b}[2J\\0bell\\u{7}");
        assert_eq!(printable(&s), s);
    }
}
