//! Streaming ENVI reader: one band row at a time through a fixed buffer.

use std::fmt;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use super::codec::{decode, Layout};
use super::{file_name, zeroed, EnviError, EnviErrorKind, EnviHeader, Interleave};

/// Read-ahead of the underlying `BufReader`; reads of a whole line bypass it.
const READ_BUFFER_BYTES: usize = 256 << 10;

/// Which row [`EnviReader::next_band_row`] produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BandRow {
    /// Band index, 0-based.
    pub band: usize,
    /// Line index, 0-based.
    pub line: usize,
}

impl fmt::Display for BandRow {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "band {} line {}", self.band, self.line)
    }
}

/// Reads an ENVI cube band row by band row without loading it.
///
/// [`open`](EnviReader::open) validates the header and checks that the data file is
/// exactly `header offset + samples * lines * bands * bytes` long before allocating
/// anything; afterwards reads fail only on I/O errors (a file truncated while open, say).
///
/// Memory: one buffer of one *unit*, the stretch of file that holds consecutive band rows:
/// a row of `samples` values for `bsq`, a line of `samples * bands` values for `bil` and
/// `bip`. Sequential reading costs one `read` per unit, so `bil` and `bip` read each line
/// once, and `bil` rows are decoded straight from contiguous bytes.
#[derive(Debug)]
pub struct EnviReader {
    hdr_path: PathBuf,
    data_path: PathBuf,
    header: EnviHeader,
    file: BufReader<File>,
    /// Position of `file`, or `None` when unknown (after an error).
    file_pos: Option<u64>,
    /// Bytes of one unit (see the type's doc).
    unit_bytes: usize,
    unit: Vec<u8>,
    loaded_unit: Option<usize>,
    /// Scratch for a random-access `bil` row (empty for other interleaves).
    row: Vec<u8>,
    next: usize,
    total_rows: usize,
    scale: Option<f64>,
}

impl EnviReader {
    /// Opens the cube whose header is `hdr_path` (`NAME.hdr`).
    ///
    /// The data file is the first of `NAME.img`, `NAME.raw`, `NAME.dat`, `NAME` that
    /// exists, then the upper-case and interleave-named variants (`NAME.IMG`, `NAME.bil`,
    /// ...) that other ENVI readers also accept.
    pub fn open(hdr_path: impl AsRef<Path>) -> Result<Self, EnviError> {
        let hdr_path = hdr_path.as_ref();
        let base =
            header_base(hdr_path).ok_or_else(|| EnviErrorKind::NotAHeaderPath.at(hdr_path))?;
        let header = EnviHeader::read(hdr_path)?;
        let data_path =
            find_data_file(&base, header.interleave).map_err(|kind| kind.at(hdr_path))?;

        super::header::not_special(&data_path)
            .map_err(|e| EnviErrorKind::io("cannot open data", e).at(&data_path))?;
        let file = File::open(&data_path)
            .map_err(|e| EnviErrorKind::io("cannot open data", e).at(&data_path))?;
        let actual = file
            .metadata()
            .map_err(|e| EnviErrorKind::io("cannot read data size", e).at(&data_path))?
            .len();
        // `validate` (run by `read`) guarantees `file_bytes` is `Some`.
        let expected = header.file_bytes().unwrap_or(u64::MAX);
        if actual != expected {
            return Err(EnviErrorKind::SizeMismatch {
                actual,
                header: file_name(hdr_path),
                samples: header.samples,
                lines: header.lines,
                bands: header.bands,
                data_type: header.data_type.name(),
                offset: header.header_offset,
                expected,
            }
            .at(&data_path));
        }
        // From here on every size derived from the header is at most the file's size.
        let value_bytes = header.data_type.bytes();
        let row_bytes = header.samples * value_bytes;
        let unit_bytes = match header.interleave {
            Interleave::Bsq => row_bytes,
            Interleave::Bil | Interleave::Bip => row_bytes * header.bands,
        };
        let row = match header.interleave {
            Interleave::Bil => row_bytes,
            Interleave::Bsq | Interleave::Bip => 0,
        };
        let row = zeroed(row).map_err(|kind| kind.at(&data_path))?;
        let unit = zeroed(unit_bytes).map_err(|kind| kind.at(&data_path))?;
        let scale = header
            .reflectance_scale_factor
            .filter(|_| header.data_type.is_integer());
        Ok(Self {
            hdr_path: hdr_path.to_path_buf(),
            data_path,
            total_rows: header.lines * header.bands,
            header,
            file: BufReader::with_capacity(READ_BUFFER_BYTES, file),
            file_pos: Some(0),
            unit_bytes,
            unit,
            loaded_unit: None,
            row,
            next: 0,
            scale,
        })
    }

    /// The validated header.
    pub fn header(&self) -> &EnviHeader {
        &self.header
    }

    /// The header file's path, as given to [`open`](EnviReader::open).
    pub fn path(&self) -> &Path {
        &self.hdr_path
    }

    /// The data file found beside the header.
    pub fn data_path(&self) -> &Path {
        &self.data_path
    }

    /// Band rows in the cube (`lines * bands`).
    pub fn rows_total(&self) -> usize {
        self.total_rows
    }

    /// Band rows [`next_band_row`](EnviReader::next_band_row) has produced since the
    /// start or the last [`rewind`](EnviReader::rewind).
    pub fn rows_read(&self) -> usize {
        self.next
    }

    /// Restarts [`next_band_row`](EnviReader::next_band_row) at the first row.
    pub fn rewind(&mut self) {
        self.next = 0;
    }

    /// Reads the next band row in the file's native order into `out` (`samples` long)
    /// and says which it was, or returns `Ok(None)` after the last one.
    ///
    /// Native order: `bsq` gives band 0 lines 0.., band 1 lines 0.., ...; `bil` and `bip`
    /// give line 0 bands 0.., line 1 bands 0.., ... Values are converted to `f32`; integer
    /// values are divided by `reflectance scale factor` when the header has one.
    /// Interleaving [`read_band_row`](EnviReader::read_band_row) calls does not disturb
    /// the sequence.
    pub fn next_band_row(&mut self, out: &mut [f32]) -> Result<Option<BandRow>, EnviError> {
        self.check_out(out)?;
        if self.next >= self.total_rows {
            return Ok(None);
        }
        let k = self.next;
        let (lines, bands) = (self.header.lines, self.header.bands);
        let (row, unit) = match self.header.interleave {
            Interleave::Bsq => (
                BandRow {
                    band: k / lines,
                    line: k % lines,
                },
                k,
            ),
            Interleave::Bil | Interleave::Bip => (
                BandRow {
                    band: k % bands,
                    line: k / bands,
                },
                k / bands,
            ),
        };
        self.load_unit(unit)?;
        self.decode_from_unit(row.band, out);
        self.next += 1;
        Ok(Some(row))
    }

    /// Reads band row (`band`, `line`) into `out` (`samples` long), seeking as needed.
    ///
    /// Reads one row for `bsq` and `bil`, and the whole line for `bip` (kept, so reading
    /// the other bands of that line costs nothing more).
    pub fn read_band_row(
        &mut self,
        band: usize,
        line: usize,
        out: &mut [f32],
    ) -> Result<(), EnviError> {
        self.check_out(out)?;
        let (lines, bands) = (self.header.lines, self.header.bands);
        if band >= bands || line >= lines {
            return Err(EnviErrorKind::OutOfRange {
                band,
                line,
                bands,
                lines,
            }
            .at(&self.data_path));
        }
        match self.header.interleave {
            Interleave::Bsq => {
                self.load_unit(band * lines + line)?;
                self.decode_from_unit(band, out);
            }
            Interleave::Bip => {
                self.load_unit(line)?;
                self.decode_from_unit(band, out);
            }
            Interleave::Bil if self.loaded_unit == Some(line) => self.decode_from_unit(band, out),
            Interleave::Bil => {
                let offset = (line * bands + band) as u64 * self.row.len() as u64;
                let mut row = std::mem::take(&mut self.row);
                let read = self.read_at(offset, &mut row);
                let layout = Layout {
                    first: 0,
                    stride: 1,
                };
                if read.is_ok() {
                    decode(
                        &row,
                        self.header.data_type,
                        self.header.byte_order,
                        layout,
                        self.scale,
                        out,
                    );
                }
                self.row = row;
                read?;
            }
        }
        Ok(())
    }

    /// Reads all of `line` at once for `bil` and `bip` (one read of its every band), so that
    /// [`read_band_row`](EnviReader::read_band_row) of its bands decodes from memory; `bsq`
    /// lines are not contiguous, and are read row by row.
    pub fn load_line(&mut self, line: usize) -> Result<(), EnviError> {
        let (lines, bands) = (self.header.lines, self.header.bands);
        if line >= lines {
            return Err(EnviErrorKind::OutOfRange {
                band: 0,
                line,
                bands,
                lines,
            }
            .at(&self.data_path));
        }
        match self.header.interleave {
            Interleave::Bsq => Ok(()),
            Interleave::Bil | Interleave::Bip => self.load_unit(line),
        }
    }

    fn check_out(&self, out: &[f32]) -> Result<(), EnviError> {
        if out.len() == self.header.samples {
            Ok(())
        } else {
            Err(EnviErrorKind::BufferLength {
                expected: self.header.samples,
                got: out.len(),
            }
            .at(&self.data_path))
        }
    }

    /// Makes `unit` the content of `self.unit`.
    fn load_unit(&mut self, unit: usize) -> Result<(), EnviError> {
        if self.loaded_unit == Some(unit) {
            return Ok(());
        }
        self.loaded_unit = None;
        let offset = unit as u64 * self.unit_bytes as u64;
        let mut buf = std::mem::take(&mut self.unit);
        let read = self.read_at(offset, &mut buf);
        self.unit = buf;
        read?;
        self.loaded_unit = Some(unit);
        Ok(())
    }

    /// Fills `buf` from data offset `offset` (after the header offset), seeking only when
    /// the file is not already there.
    fn read_at(&mut self, offset: u64, buf: &mut [u8]) -> Result<(), EnviError> {
        let pos = self.header.header_offset + offset;
        if self.file_pos != Some(pos) {
            self.file_pos = None;
            self.file
                .seek(SeekFrom::Start(pos))
                .map_err(|e| EnviErrorKind::io("cannot seek in data", e).at(&self.data_path))?;
        }
        self.file_pos = None;
        self.file
            .read_exact(buf)
            .map_err(|e| EnviErrorKind::io("cannot read data", e).at(&self.data_path))?;
        self.file_pos = Some(pos + buf.len() as u64);
        Ok(())
    }

    /// Decodes `band`'s row from the loaded unit.
    fn decode_from_unit(&self, band: usize, out: &mut [f32]) {
        let samples = self.header.samples;
        let layout = match self.header.interleave {
            Interleave::Bsq => Layout {
                first: 0,
                stride: 1,
            },
            Interleave::Bil => Layout {
                first: band * samples,
                stride: 1,
            },
            Interleave::Bip => Layout {
                first: band,
                stride: self.header.bands,
            },
        };
        decode(
            &self.unit,
            self.header.data_type,
            self.header.byte_order,
            layout,
            self.scale,
            out,
        );
    }
}

/// `NAME` for `NAME.hdr` (any case), or `None` for other paths.
pub(super) fn header_base(hdr_path: &Path) -> Option<PathBuf> {
    let ext = hdr_path.extension()?;
    if !ext.eq_ignore_ascii_case("hdr") {
        return None;
    }
    Some(hdr_path.with_extension(""))
}

/// Finds the data file for header base `NAME`.
fn find_data_file(base: &Path, interleave: Interleave) -> Result<PathBuf, EnviErrorKind> {
    let mut candidates: Vec<PathBuf> = ["img", "raw", "dat"]
        .iter()
        .map(|ext| with_suffix(base, ext))
        .collect();
    candidates.push(base.to_path_buf());
    for ext in ["IMG", "RAW", "DAT", interleave.name()] {
        candidates.push(with_suffix(base, ext));
    }
    if let Some(found) = candidates.iter().find(|p| p.is_file()) {
        return Ok(found.clone());
    }
    let tried = candidates
        .iter()
        .take(4)
        .map(|p| file_name(p))
        .collect::<Vec<_>>()
        .join(", ");
    Err(EnviErrorKind::DataNotFound { tried })
}

/// `base` + `.ext`, keeping any dots already in `base`'s name.
pub(super) fn with_suffix(base: &Path, ext: &str) -> PathBuf {
    let mut name = base.as_os_str().to_os_string();
    name.push(".");
    name.push(ext);
    PathBuf::from(name)
}

/// A whole cube in memory, for tests and small data; [`EnviReader`] streams instead.
#[derive(Clone, Debug, PartialEq)]
pub struct Cube {
    /// Pixels per line.
    pub samples: usize,
    /// Lines.
    pub lines: usize,
    /// Bands.
    pub bands: usize,
    /// Values in BSQ order: index `(band * lines + line) * samples + sample`.
    pub data: Vec<f32>,
    /// The cube's header.
    pub header: EnviHeader,
}

impl Cube {
    /// The value at (`band`, `line`, `sample`), or `None` outside the cube.
    pub fn get(&self, band: usize, line: usize, sample: usize) -> Option<f32> {
        if band >= self.bands || line >= self.lines || sample >= self.samples {
            return None;
        }
        self.data
            .get((band * self.lines + line) * self.samples + sample)
            .copied()
    }

    /// The `samples` values of band row (`band`, `line`), or `None` outside the cube.
    pub fn row(&self, band: usize, line: usize) -> Option<&[f32]> {
        if band >= self.bands || line >= self.lines {
            return None;
        }
        let start = (band * self.lines + line) * self.samples;
        self.data.get(start..start + self.samples)
    }
}

/// Reads the whole cube whose header is `hdr_path` into memory (as `f32`, BSQ order).
pub fn read_cube(hdr_path: impl AsRef<Path>) -> Result<Cube, EnviError> {
    let mut reader = EnviReader::open(hdr_path)?;
    let header = reader.header().clone();
    let (samples, lines, bands) = (header.samples, header.lines, header.bands);
    // The data file holds `values` values, so this allocation is bounded by its size.
    let values = header.values().unwrap_or(0);
    let mut data = zeroed::<f32>(values).map_err(|kind| kind.at(reader.data_path()))?;
    let mut row = zeroed::<f32>(samples).map_err(|kind| kind.at(reader.data_path()))?;
    while let Some(BandRow { band, line }) = reader.next_band_row(&mut row)? {
        let start = (band * lines + line) * samples;
        if let Some(dst) = data.get_mut(start..start + samples) {
            dst.copy_from_slice(&row);
        }
    }
    Ok(Cube {
        samples,
        lines,
        bands,
        data,
        header,
    })
}
