//! The ENVI text header: parsing, validation and writing.

use std::fmt::Write as _;
use std::io::Read as _;
use std::path::Path;

use super::{shorten, EnviError, EnviErrorKind};

/// Headers larger than this are refused (a data file passed by mistake, say).
const MAX_HEADER_BYTES: u64 = 16 << 20;

/// The `file type` of an image cube, written unless [`EnviHeader::extra`] has another.
const STANDARD_FILE_TYPE: &str = "ENVI Standard";

/// Order of values in an ENVI data file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum Interleave {
    /// Band sequential: band, line, sample.
    Bsq,
    /// Band interleaved by line: line, band, sample (what a line-scan camera delivers).
    Bil,
    /// Band interleaved by pixel: line, sample, band.
    Bip,
}

impl Interleave {
    /// Parses `bsq`, `bil` or `bip`, in any case, surrounding spaces ignored.
    pub fn from_name(name: &str) -> Option<Self> {
        match name.trim().to_ascii_lowercase().as_str() {
            "bsq" => Some(Self::Bsq),
            "bil" => Some(Self::Bil),
            "bip" => Some(Self::Bip),
            _ => None,
        }
    }

    /// The header spelling: `bsq`, `bil` or `bip`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Bsq => "bsq",
            Self::Bil => "bil",
            Self::Bip => "bip",
        }
    }
}

/// Value type of an ENVI data file (`data type` key); the types filmscope reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DataType {
    /// `2`: signed 16-bit integer.
    I16,
    /// `4`: 32-bit IEEE float (filmscope's reflectance cubes and maps).
    F32,
    /// `5`: 64-bit IEEE float.
    F64,
    /// `12`: unsigned 16-bit integer (raw camera counts).
    U16,
}

impl DataType {
    /// The type for an ENVI `data type` code, if filmscope reads it.
    pub fn from_code(code: u32) -> Option<Self> {
        match code {
            2 => Some(Self::I16),
            4 => Some(Self::F32),
            5 => Some(Self::F64),
            12 => Some(Self::U16),
            _ => None,
        }
    }

    /// The ENVI `data type` code.
    pub fn code(self) -> u32 {
        match self {
            Self::I16 => 2,
            Self::F32 => 4,
            Self::F64 => 5,
            Self::U16 => 12,
        }
    }

    /// Bytes per value.
    pub fn bytes(self) -> usize {
        match self {
            Self::I16 | Self::U16 => 2,
            Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// Whether values are integers (so `reflectance scale factor` applies).
    pub fn is_integer(self) -> bool {
        matches!(self, Self::I16 | Self::U16)
    }

    /// A short name for messages: `int16`, `float32`, `float64`, `uint16`.
    pub fn name(self) -> &'static str {
        match self {
            Self::I16 => "int16",
            Self::F32 => "float32",
            Self::F64 => "float64",
            Self::U16 => "uint16",
        }
    }

    /// The name of any ENVI data type code, read or not (for error messages).
    pub(crate) fn envi_type_name(code: &str) -> Option<&'static str> {
        Some(match code.trim() {
            "1" => "uint8",
            "2" => "int16",
            "3" => "int32",
            "4" => "float32",
            "5" => "float64",
            "6" => "complex64",
            "9" => "complex128",
            "12" => "uint16",
            "13" => "uint32",
            "14" => "int64",
            "15" => "uint64",
            _ => return None,
        })
    }
}

/// Byte order of multi-byte values (`byte order` key).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default, clap::ValueEnum)]
pub enum ByteOrder {
    /// `0`: least significant byte first.
    #[default]
    Little,
    /// `1`: most significant byte first.
    Big,
}

impl ByteOrder {
    /// The order for an ENVI `byte order` code (`0` or `1`).
    pub fn from_code(code: u32) -> Option<Self> {
        match code {
            0 => Some(Self::Little),
            1 => Some(Self::Big),
            _ => None,
        }
    }

    /// The ENVI `byte order` code.
    pub fn code(self) -> u32 {
        match self {
            Self::Little => 0,
            Self::Big => 1,
        }
    }
}

/// A parsed and validated ENVI header.
///
/// The fields are public so producers (the simulator, the writers) can build headers;
/// [`EnviHeader::validate`] checks a hand-built one, and everything that consumes a header
/// ([`EnviHeader::parse`], [`super::EnviWriter::create`]) validates it first.
#[derive(Clone, Debug, PartialEq)]
pub struct EnviHeader {
    /// Pixels per line (`samples`).
    pub samples: usize,
    /// Lines (`lines`).
    pub lines: usize,
    /// Bands (`bands`).
    pub bands: usize,
    /// Bytes to skip at the start of the data file (`header offset`, default 0).
    pub header_offset: u64,
    /// Value order in the data file (`interleave`).
    pub interleave: Interleave,
    /// Value type (`data type`).
    pub data_type: DataType,
    /// Byte order (`byte order`; little endian when the key is absent).
    pub byte_order: ByteOrder,
    /// Band centre wavelengths in nanometres (`wavelength`, converted from
    /// `wavelength units`), one per band.
    pub wavelength_nm: Option<Vec<f64>>,
    /// Band full widths at half maximum in nanometres (`fwhm`, same units as
    /// `wavelength`), one per band.
    pub fwhm_nm: Option<Vec<f64>>,
    /// `reflectance scale factor`: integer values are divided by it on reading (and
    /// multiplied by it on writing). Finite and non-zero.
    pub reflectance_scale_factor: Option<f64>,
    /// `description`, braces removed.
    pub description: Option<String>,
    /// Every other key, as `(key as spelled, raw value)`, in file order; a `{...}` value
    /// keeps its braces and line breaks. Written back by [`EnviHeader::to_text`].
    pub extra: Vec<(String, String)>,
}

/// One `key = value` entry before interpretation.
struct Entry {
    key: String,
    norm: String,
    value: String,
}

impl EnviHeader {
    /// A header with the given geometry, no offset, little endian and no optional keys.
    pub fn new(
        samples: usize,
        lines: usize,
        bands: usize,
        data_type: DataType,
        interleave: Interleave,
    ) -> Self {
        Self {
            samples,
            lines,
            bands,
            header_offset: 0,
            interleave,
            data_type,
            byte_order: ByteOrder::Little,
            wavelength_nm: None,
            fwhm_nm: None,
            reflectance_scale_factor: None,
            description: None,
            extra: Vec::new(),
        }
    }

    /// Reads and parses the header file at `path` (at most 16 MiB are read).
    pub fn read(path: &Path) -> Result<Self, EnviError> {
        not_special(path).map_err(|e| EnviErrorKind::io("cannot open header", e).at(path))?;
        let file = std::fs::File::open(path)
            .map_err(|e| EnviErrorKind::io("cannot open header", e).at(path))?;
        let mut bytes = Vec::new();
        file.take(MAX_HEADER_BYTES + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| EnviErrorKind::io("cannot read header", e).at(path))?;
        if bytes.len() as u64 > MAX_HEADER_BYTES {
            return Err(EnviErrorKind::HeaderTooLarge {
                limit: MAX_HEADER_BYTES,
            }
            .at(path));
        }
        Self::parse(&String::from_utf8_lossy(&bytes)).map_err(|kind| kind.at(path))
    }

    /// Parses and validates header text.
    ///
    /// The first line must start with `ENVI`. Then `key = value` lines follow; keys are
    /// case-insensitive, a value opened by `{` runs until the next `}` (possibly lines
    /// later), lines starting with `;` are comments and lines without `=` are skipped, as
    /// other ENVI readers do. Of repeated known keys the last wins.
    ///
    /// Wavelength units: `Nanometers` and `Micrometers` (also `nm`, `um`, `µm`, `microns`,
    /// in any case) are converted to nanometres. When `wavelength units` is absent or
    /// `Unknown`, wavelengths whose largest value is below 10 are taken as micrometres
    /// (no visible or near-infrared band lies below 10 nm) and the rest as nanometres;
    /// `fwhm` follows the wavelengths' units, or nanometres when there are no wavelengths.
    ///
    /// Required keys: `samples`, `lines`, `bands`, `data type`, `interleave`. `header
    /// offset` defaults to 0 and `byte order` to 0 (little endian).
    pub fn parse(text: &str) -> Result<Self, EnviErrorKind> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        if text.trim().is_empty() {
            return Err(EnviErrorKind::EmptyHeader);
        }
        let entries = split_entries(text)?;

        let mut samples = None;
        let mut lines = None;
        let mut bands = None;
        let mut header_offset = 0u64;
        let mut interleave = None;
        let mut data_type = None;
        let mut byte_order = ByteOrder::Little;
        let mut wavelength = None;
        let mut units = None;
        let mut fwhm = None;
        let mut scale = None;
        let mut description = None;
        let mut extra = Vec::new();

        for Entry { key, norm, value } in entries {
            match norm.as_str() {
                "samples" => samples = Some(parse_usize(&key, &value)?),
                "lines" => lines = Some(parse_usize(&key, &value)?),
                "bands" => bands = Some(parse_usize(&key, &value)?),
                "header offset" => header_offset = parse_u64(&key, &value)?,
                "interleave" => {
                    interleave = Some(Interleave::from_name(&value).ok_or_else(|| {
                        EnviErrorKind::UnknownInterleave {
                            value: shorten(&value),
                        }
                    })?)
                }
                "data type" => {
                    let code = value
                        .trim()
                        .parse::<u32>()
                        .ok()
                        .and_then(DataType::from_code);
                    data_type = Some(code.ok_or_else(|| EnviErrorKind::UnsupportedDataType {
                        code: shorten(&value),
                    })?)
                }
                "byte order" => {
                    byte_order = value
                        .trim()
                        .parse::<u32>()
                        .ok()
                        .and_then(ByteOrder::from_code)
                        .ok_or_else(|| bad(&key, &value, "0 (little endian) or 1 (big endian)"))?
                }
                "wavelength" => wavelength = Some(parse_list(&key, &value)?),
                "wavelength units" => units = Some(value),
                "fwhm" => fwhm = Some(parse_list(&key, &value)?),
                "reflectance scale factor" => {
                    let factor = parse_f64(&key, &value)?;
                    if !factor.is_finite() || factor == 0.0 {
                        return Err(bad(&key, &value, "a finite, non-zero number"));
                    }
                    scale = Some(factor)
                }
                "description" => description = Some(brace_inner(&value).trim().to_string()),
                // The default `to_text` writes back; other file types are kept verbatim.
                "file type" if value.trim().eq_ignore_ascii_case(STANDARD_FILE_TYPE) => {}
                _ => extra.push((key, value)),
            }
        }

        let samples = samples.ok_or(EnviErrorKind::MissingKey { key: "samples" })?;
        let lines = lines.ok_or(EnviErrorKind::MissingKey { key: "lines" })?;
        let bands = bands.ok_or(EnviErrorKind::MissingKey { key: "bands" })?;
        let data_type = data_type.ok_or(EnviErrorKind::MissingKey { key: "data type" })?;
        let interleave = interleave.ok_or(EnviErrorKind::MissingKey { key: "interleave" })?;

        let to_nm = match units.as_deref() {
            Some(u) => match unit_factor(u) {
                Some(UnitFactor::Known(f)) => f,
                Some(UnitFactor::Unknown) => guess_factor(wavelength.as_deref()),
                None => return Err(EnviErrorKind::UnknownUnits { value: shorten(u) }),
            },
            None => guess_factor(wavelength.as_deref()),
        };
        let scale_list = |list: Option<Vec<f64>>| {
            list.map(|values| values.into_iter().map(|v| v * to_nm).collect::<Vec<_>>())
        };

        let header = Self {
            samples,
            lines,
            bands,
            header_offset,
            interleave,
            data_type,
            byte_order,
            wavelength_nm: scale_list(wavelength),
            fwhm_nm: scale_list(fwhm),
            reflectance_scale_factor: scale,
            description,
            extra,
        };
        header.validate()?;
        Ok(header)
    }

    /// Checks the invariants every consumer relies on: positive dimensions, sizes that fit
    /// in 64 bits and in memory addresses, one finite wavelength and FWHM per band, a
    /// finite non-zero scale factor, and extra keys that can be written back.
    pub fn validate(&self) -> Result<(), EnviErrorKind> {
        for (key, value) in [
            ("samples", self.samples),
            ("lines", self.lines),
            ("bands", self.bands),
        ] {
            if value == 0 {
                return Err(EnviErrorKind::ZeroDimension { key });
            }
        }
        if self.file_bytes().is_none() {
            return Err(EnviErrorKind::TooLarge {
                samples: self.samples,
                lines: self.lines,
                bands: self.bands,
                data_type: self.data_type.name(),
            });
        }
        for (key, list) in [("wavelength", &self.wavelength_nm), ("fwhm", &self.fwhm_nm)] {
            if let Some(list) = list {
                if list.len() != self.bands {
                    return Err(EnviErrorKind::CountMismatch {
                        key,
                        count: list.len(),
                        bands: self.bands,
                    });
                }
                if let Some(v) = list.iter().find(|v| !v.is_finite()) {
                    return Err(bad(key, &v.to_string(), "finite numbers"));
                }
            }
        }
        if let Some(f) = self.reflectance_scale_factor {
            if !f.is_finite() || f == 0.0 {
                return Err(bad(
                    "reflectance scale factor",
                    &f.to_string(),
                    "a finite, non-zero number",
                ));
            }
        }
        for (key, value) in &self.extra {
            let bad_key = key.trim().is_empty() || key.contains(['=', '\n', '\r', '{', '}']);
            let bad_value = value.contains(['\n', '\r']) && !value.trim_start().starts_with('{');
            if bad_key || bad_value {
                return Err(EnviErrorKind::BadExtraKey { key: shorten(key) });
            }
        }
        Ok(())
    }

    /// Values in the cube, `samples * lines * bands`, if that fits in a `usize`.
    pub fn values(&self) -> Option<usize> {
        self.samples
            .checked_mul(self.lines)
            .and_then(|n| n.checked_mul(self.bands))
    }

    /// Bytes of cube data, excluding the header offset, if that fits in 64 bits and in a
    /// `usize`.
    pub fn data_bytes(&self) -> Option<u64> {
        let bytes = self.values()?.checked_mul(self.data_type.bytes())?;
        u64::try_from(bytes).ok()
    }

    /// The data file's expected size: header offset plus cube data.
    pub fn file_bytes(&self) -> Option<u64> {
        self.data_bytes()?.checked_add(self.header_offset)
    }

    /// Renders the header as ENVI text (wavelengths and FWHM in nanometres).
    ///
    /// Parsing the result gives back an equal header, apart from braces in the description,
    /// which are replaced by parentheses, and description lines starting with `;`, which
    /// join the line before (ENVI reads them as comments).
    pub fn to_text(&self) -> String {
        let mut out = String::from("ENVI\n");
        // Writing to a String cannot fail; `let _` keeps the function infallible.
        if let Some(description) = &self.description {
            let clean = description.replace('{', "(").replace('}', ")");
            out.push_str("description = {");
            for line in clean.trim().lines() {
                let line = line.trim();
                // A continuation line starting with `;` would be read as a comment (and a
                // lone `;}` would leave the brace open): keep such text on the line before.
                if line.starts_with(';') {
                    out.push(' ');
                } else {
                    out.push_str("\n  ");
                }
                out.push_str(line);
            }
            out.push_str("}\n");
        }
        let _ = writeln!(out, "samples = {}", self.samples);
        let _ = writeln!(out, "lines = {}", self.lines);
        let _ = writeln!(out, "bands = {}", self.bands);
        let _ = writeln!(out, "header offset = {}", self.header_offset);
        if !self.has_extra("file type") {
            let _ = writeln!(out, "file type = {STANDARD_FILE_TYPE}");
        }
        let _ = writeln!(out, "data type = {}", self.data_type.code());
        let _ = writeln!(out, "interleave = {}", self.interleave.name());
        let _ = writeln!(out, "byte order = {}", self.byte_order.code());
        if let Some(f) = self.reflectance_scale_factor {
            let _ = writeln!(out, "reflectance scale factor = {f}");
        }
        if self.wavelength_nm.is_some() || self.fwhm_nm.is_some() {
            out.push_str("wavelength units = Nanometers\n");
        }
        for (key, list) in [("wavelength", &self.wavelength_nm), ("fwhm", &self.fwhm_nm)] {
            if let Some(list) = list {
                let _ = write!(out, "{key} = {{");
                for (i, v) in list.iter().enumerate() {
                    let sep = if i == 0 { " " } else { ", " };
                    let _ = write!(out, "{sep}{v}");
                }
                out.push_str(" }\n");
            }
        }
        for (key, value) in &self.extra {
            let _ = writeln!(out, "{} = {}", key.trim(), value.trim());
        }
        out
    }

    /// `"64x32x3 float32"`: samples x lines x bands and value type, for messages.
    pub fn shape_text(&self) -> String {
        format!(
            "{}x{}x{} {}",
            self.samples,
            self.lines,
            self.bands,
            self.data_type.name()
        )
    }

    fn has_extra(&self, norm_key: &str) -> bool {
        self.extra.iter().any(|(k, _)| normalize_key(k) == norm_key)
    }
}

/// Splits header text into entries, joining `{...}` values that span lines.
fn split_entries(text: &str) -> Result<Vec<Entry>, EnviErrorKind> {
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, first)) if first.trim_start().starts_with("ENVI") => {}
        _ => return Err(EnviErrorKind::NotEnvi),
    }
    let mut entries = Vec::new();
    while let Some((index, line)) = lines.next() {
        let line = line.trim();
        if line.is_empty() || line.starts_with(';') {
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            continue;
        };
        let key = key.trim();
        if key.is_empty() {
            continue;
        }
        let mut value = value.trim().to_string();
        if value.starts_with('{') {
            while !value.contains('}') {
                match lines.next() {
                    Some((_, next)) => {
                        let next = next.trim();
                        if next.starts_with(';') {
                            continue;
                        }
                        value.push('\n');
                        value.push_str(next);
                    }
                    None => {
                        return Err(EnviErrorKind::UnclosedBrace {
                            key: shorten(key),
                            line: index + 1,
                        })
                    }
                }
            }
            if let Some(end) = value.find('}') {
                value.truncate(end + 1);
            }
        }
        entries.push(Entry {
            key: key.to_string(),
            norm: normalize_key(key),
            value,
        });
    }
    Ok(entries)
}

/// Lower case, runs of white space collapsed to one space.
fn normalize_key(key: &str) -> String {
    key.split_whitespace()
        .map(str::to_ascii_lowercase)
        .collect::<Vec<_>>()
        .join(" ")
}

/// The text between `{` and `}`, or the value itself if it has no braces.
fn brace_inner(value: &str) -> &str {
    let v = value.trim();
    match v.strip_prefix('{') {
        Some(rest) => rest.strip_suffix('}').unwrap_or(rest),
        None => v,
    }
}

fn bad(key: &str, value: &str, expected: &'static str) -> EnviErrorKind {
    EnviErrorKind::BadValue {
        key: key.to_string(),
        value: shorten(value),
        expected,
    }
}

fn parse_usize(key: &str, value: &str) -> Result<usize, EnviErrorKind> {
    value
        .trim()
        .parse::<usize>()
        .map_err(|_| bad(key, value, "a non-negative integer"))
}

fn parse_u64(key: &str, value: &str) -> Result<u64, EnviErrorKind> {
    value
        .trim()
        .parse::<u64>()
        .map_err(|_| bad(key, value, "a non-negative integer"))
}

fn parse_f64(key: &str, value: &str) -> Result<f64, EnviErrorKind> {
    value
        .trim()
        .parse::<f64>()
        .map_err(|_| bad(key, value, "a number"))
}

/// Parses `{ a, b, c }` (a single bare number is a one-element list). One trailing comma
/// is tolerated; any other empty item is an error.
fn parse_list(key: &str, value: &str) -> Result<Vec<f64>, EnviErrorKind> {
    let inner = brace_inner(value);
    let mut items: Vec<&str> = inner.split(',').map(str::trim).collect();
    if items.last().is_some_and(|s| s.is_empty()) {
        items.pop();
    }
    items
        .into_iter()
        .map(|item| {
            item.parse::<f64>()
                .map_err(|_| bad(key, value, "a `{...}` list of numbers"))
        })
        .collect()
}

enum UnitFactor {
    Known(f64),
    Unknown,
}

fn unit_factor(units: &str) -> Option<UnitFactor> {
    let u = units.trim().to_lowercase();
    match u.as_str() {
        "nanometers" | "nanometer" | "nanometres" | "nanometre" | "nm" => {
            Some(UnitFactor::Known(1.0))
        }
        "micrometers" | "micrometer" | "micrometres" | "micrometre" | "microns" | "micron"
        | "um" | "µm" | "μm" => Some(UnitFactor::Known(1000.0)),
        "unknown" | "" => Some(UnitFactor::Unknown),
        _ => None,
    }
}

/// Without units: wavelengths all below 10 are micrometres, the rest nanometres.
fn guess_factor(wavelengths: Option<&[f64]>) -> f64 {
    match wavelengths {
        Some(list) if !list.is_empty() && list.iter().all(|&v| v < 10.0) => 1000.0,
        _ => 1.0,
    }
}

/// Refuses FIFOs, devices and directories: opening or reading them would block or never
/// end (a FIFO named as a header, `/dev/zero` as a data file).
pub(crate) fn not_special(path: &Path) -> std::io::Result<()> {
    let meta = std::fs::metadata(path)?;
    if meta.is_file() {
        Ok(())
    } else {
        Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file (a FIFO, device or directory)",
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BASIC: &str =
        "ENVI\nsamples = 5\nlines = 3\nbands = 4\ndata type = 4\ninterleave = bsq\n";

    /// Found by `fuzz envi_header`: a description whose text starts with `;` was written as
    /// a continuation line `;...}`, which readers skip as a comment, so the brace never
    /// closed and the rewritten header lost every key after it.
    #[test]
    fn fuzz_description_starting_with_a_semicolon_round_trips() -> Result<(), EnviErrorKind> {
        for description in [
            "description = ;",
            "description = ;{",
            "description = { ; a\n b }",
        ] {
            let h = EnviHeader::parse(&format!("{BASIC}{description}\n"))?;
            let again = EnviHeader::parse(&h.to_text())?;
            assert_eq!((again.samples, again.lines, again.bands), (5, 3, 4));
            assert!(again.description.is_some(), "{description}");
        }
        Ok(())
    }

    #[test]
    fn parses_minimal_header_with_defaults() -> Result<(), EnviErrorKind> {
        let h = EnviHeader::parse(BASIC)?;
        assert_eq!((h.samples, h.lines, h.bands), (5, 3, 4));
        assert_eq!(h.header_offset, 0);
        assert_eq!(h.byte_order, ByteOrder::Little);
        assert_eq!(h.data_type, DataType::F32);
        assert_eq!(h.interleave, Interleave::Bsq);
        assert_eq!(h.wavelength_nm, None);
        Ok(())
    }

    #[test]
    fn keys_and_values_are_case_insensitive_and_lists_span_lines() -> Result<(), EnviErrorKind> {
        let text = "ENVI\nSamples = 5\nLINES= 3\nBands =4\nData Type = 12\nInterleave = BIL\n\
                    Byte Order = 1\nWavelength Units = MICROMETERS\n; a comment\n\
                    Wavelength = {\n 0.45,\n 0.5,\n; inside\n 0.55, 0.6\n}\n\
                    fwhm = {0.01, 0.01, 0.01, 0.01,}\nmap info = {UTM, 1, 1}\n";
        let h = EnviHeader::parse(text)?;
        assert_eq!(h.interleave, Interleave::Bil);
        assert_eq!(h.data_type, DataType::U16);
        assert_eq!(h.byte_order, ByteOrder::Big);
        let wl = h.wavelength_nm.clone().unwrap_or_default();
        assert_eq!(wl.len(), 4);
        assert!((wl[0] - 450.0).abs() < 1e-9 && (wl[3] - 600.0).abs() < 1e-9);
        assert_eq!(h.fwhm_nm.as_ref().map(Vec::len), Some(4));
        assert_eq!(
            h.extra,
            vec![("map info".to_string(), "{UTM, 1, 1}".to_string())]
        );
        Ok(())
    }

    #[test]
    fn unitless_small_wavelengths_are_micrometres() -> Result<(), EnviErrorKind> {
        let h = EnviHeader::parse(&format!("{BASIC}wavelength = {{0.4,0.5,0.6,0.7}}\n"))?;
        assert_eq!(h.wavelength_nm.map(|w| w[0].round()), Some(400.0));
        let h = EnviHeader::parse(&format!("{BASIC}wavelength = {{400,500,600,700}}\n"))?;
        assert_eq!(h.wavelength_nm.map(|w| w[0]), Some(400.0));
        Ok(())
    }

    #[test]
    fn text_round_trips() -> Result<(), EnviErrorKind> {
        let mut h = EnviHeader::new(7, 2, 3, DataType::U16, Interleave::Bip);
        h.header_offset = 16;
        h.byte_order = ByteOrder::Big;
        h.wavelength_nm = Some(vec![450.5, 550.0, 650.25]);
        h.fwhm_nm = Some(vec![10.0, 10.0, 12.5]);
        h.reflectance_scale_factor = Some(10000.0);
        h.description = Some("two\nlines".to_string());
        h.extra = vec![
            ("sensor type".to_string(), "LCTF".to_string()),
            ("band names".to_string(), "{a,\nb, c}".to_string()),
        ];
        let back = EnviHeader::parse(&h.to_text())?;
        assert_eq!(back, h);
        Ok(())
    }

    #[test]
    fn rejects_bad_headers_without_panicking() {
        let cases: &[(&str, &str)] = &[
            ("", "empty"),
            ("\u{0}\u{1}garbage", "not an ENVI header"),
            ("ENVI\nsamples = 5\n", "missing required key `lines`"),
            (
                "ENVI\nsamples=1\nlines=1\nbands=1\ndata type=6\ninterleave=bsq\n",
                "data type 6 (complex64) is not supported",
            ),
            (
                "ENVI\nsamples=1\nlines=1\nbands=1\ndata type=4\ninterleave=bsx\n",
                "unknown interleave `bsx`",
            ),
            (
                "ENVI\nsamples=1\nlines=1\nbands=2\ndata type=4\ninterleave=bsq\nwavelength={1}\n",
                "`wavelength` lists 1 values but `bands` is 2",
            ),
            (
                "ENVI\nsamples=0\nlines=1\nbands=1\ndata type=4\ninterleave=bsq\n",
                "`samples` must be positive",
            ),
            (
                "ENVI\nsamples=-3\nlines=1\nbands=1\ndata type=4\ninterleave=bsq\n",
                "`samples = -3`: expected a non-negative integer",
            ),
            (
                "ENVI\nsamples=1\nlines=1\nbands=1\ndata type=4\ninterleave=bsq\nwavelength={1,\n",
                "never closed",
            ),
            (
                "ENVI\nsamples=18446744073709551615\nlines=2\nbands=1\ndata type=4\ninterleave=bsq\n",
                "overflows",
            ),
            (
                "ENVI\nsamples=1\nlines=1\nbands=1\ndata type=4\ninterleave=bsq\nbyte order=2\n",
                "`byte order = 2`",
            ),
            (
                "ENVI\nsamples=1\nlines=1\nbands=1\ndata type=4\ninterleave=bsq\nwavelength units=GHz\n",
                "unsupported wavelength units `GHz`",
            ),
        ];
        for (text, want) in cases {
            match EnviHeader::parse(text) {
                Ok(h) => panic!("{text:?} parsed as {h:?}"),
                Err(e) => {
                    let msg = e.to_string();
                    assert!(msg.contains(want), "{text:?}: {msg:?} lacks {want:?}");
                    assert!(!msg.contains('\n'), "multi-line message {msg:?}");
                }
            }
        }
    }
}
