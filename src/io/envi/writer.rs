//! ENVI writer: band rows in any order into a pre-sized temporary file, renamed into place.

use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::codec::{encode, Layout};
use super::reader::{header_base, with_suffix};
use super::{zeroed, DataType, EnviError, EnviErrorKind, EnviHeader, Interleave};
use crate::io::atomic::TempFile;

/// Writes an ENVI cube (`NAME.hdr` + `NAME.img`) band row by band row.
///
/// The data goes to a temporary file beside the target, sized up front to
/// `header offset + samples * lines * bands * bytes` (zeros, so rows never written read
/// back as 0); each [`write_band_row`](EnviWriter::write_band_row) writes at its own offset,
/// so rows may come in any order. [`finish`](EnviWriter::finish) writes the header and
/// renames both files into place, data first: an interrupted run leaves the previous files
/// (or none) and no partial one. Dropping the writer without `finish` removes the temporary
/// file.
///
/// Writes float32 and uint16 (`data type` 4 and 12), either byte order (little endian
/// unless the header says otherwise), any interleave. uint16 values are multiplied by
/// `reflectance scale factor` when the header has one, rounded to nearest and clamped to
/// 0..=65535 (NaN becomes 0).
///
/// Memory: up to `PENDING_BYTES` (1 MiB) of encoded rows that continue one another, gathered
/// into one write (rows written in the file's own order reach the file in large writes,
/// not one call a row), plus one line for `bip` (whose rows are not contiguous: the line
/// is read, patched and written back when another line is addressed, so writing all bands
/// of a line before the next costs one read and one write per line).
#[derive(Debug)]
pub struct EnviWriter {
    hdr_path: PathBuf,
    data_path: PathBuf,
    header: EnviHeader,
    data: TempFile,
    /// Position of the temporary file, or `None` when unknown.
    pos: Option<u64>,
    row_bytes: usize,
    /// `bip` only: the cached line, its index and whether it differs from the file.
    line: Vec<u8>,
    cached_line: Option<usize>,
    dirty: bool,
    scale: Option<f64>,
    /// Bytes that continue the file from `pos - pending.len()`, not yet written.
    pending: Vec<u8>,
}

/// Most bytes an [`EnviWriter`] gathers before writing them.
pub const PENDING_BYTES: usize = 1 << 20;

impl EnviWriter {
    /// Starts writing the cube described by `header` to `hdr_path` (`NAME.hdr`, data in
    /// `NAME.img`).
    pub fn create(hdr_path: impl AsRef<Path>, header: &EnviHeader) -> Result<Self, EnviError> {
        let hdr_path = hdr_path.as_ref();
        let base =
            header_base(hdr_path).ok_or_else(|| EnviErrorKind::NotAHeaderPath.at(hdr_path))?;
        header.validate().map_err(|kind| kind.at(hdr_path))?;
        if !matches!(header.data_type, DataType::F32 | DataType::U16) {
            return Err(EnviErrorKind::UnsupportedWrite {
                data_type: header.data_type.name(),
            }
            .at(hdr_path));
        }
        let data_path = with_suffix(&base, "img");
        let file_bytes = header.file_bytes().unwrap_or(u64::MAX);
        let mut data = TempFile::create(&data_path)
            .map_err(|e| EnviErrorKind::io("cannot create data", e).at(&data_path))?;
        data.file_mut()
            .set_len(file_bytes)
            .map_err(|e| EnviErrorKind::io("cannot size data", e).at(&data_path))?;
        let row_bytes = header.samples * header.data_type.bytes();
        let line_bytes = match header.interleave {
            Interleave::Bip => row_bytes * header.bands,
            Interleave::Bsq | Interleave::Bil => 0,
        };
        let line = zeroed(line_bytes).map_err(|kind| kind.at(&data_path))?;
        let scale = header
            .reflectance_scale_factor
            .filter(|_| header.data_type.is_integer());
        Ok(Self {
            hdr_path: hdr_path.to_path_buf(),
            data_path,
            header: header.clone(),
            data,
            pos: Some(0),
            row_bytes,
            line,
            cached_line: None,
            dirty: false,
            scale,
            pending: Vec::new(),
        })
    }

    /// The header being written.
    pub fn header(&self) -> &EnviHeader {
        &self.header
    }

    /// The header path given to [`create`](EnviWriter::create).
    pub fn path(&self) -> &Path {
        &self.hdr_path
    }

    /// The data file the cube will have after [`finish`](EnviWriter::finish).
    pub fn data_path(&self) -> &Path {
        &self.data_path
    }

    /// Writes the `samples` values of band row (`band`, `line`). Writing a row twice keeps
    /// the second.
    pub fn write_band_row(
        &mut self,
        band: usize,
        line: usize,
        values: &[f32],
    ) -> Result<(), EnviError> {
        let (samples, lines, bands) = (self.header.samples, self.header.lines, self.header.bands);
        if values.len() != samples {
            return Err(EnviErrorKind::BufferLength {
                expected: samples,
                got: values.len(),
            }
            .at(&self.data_path));
        }
        if band >= bands || line >= lines {
            return Err(EnviErrorKind::OutOfRange {
                band,
                line,
                bands,
                lines,
            }
            .at(&self.data_path));
        }
        let (dt, order) = (self.header.data_type, self.header.byte_order);
        let contiguous = Layout {
            first: 0,
            stride: 1,
        };
        let row_index = match self.header.interleave {
            Interleave::Bsq => band * lines + line,
            Interleave::Bil => line * bands + band,
            Interleave::Bip => {
                self.load_line(line)?;
                let layout = Layout {
                    first: band,
                    stride: bands,
                };
                encode(values, dt, order, layout, self.scale, &mut self.line);
                self.dirty = true;
                return Ok(());
            }
        };
        // Encoded straight into the gathered bytes (flushed first unless the row continues
        // them and fits).
        let pos = self.header.header_offset + row_index as u64 * self.row_bytes as u64;
        self.seek_to(pos)?;
        if self.pending.len() + self.row_bytes > PENDING_BYTES {
            self.flush_pending()?;
        }
        let start = self.pending.len();
        self.pending.resize(start + self.row_bytes, 0);
        encode(
            values,
            dt,
            order,
            contiguous,
            self.scale,
            &mut self.pending[start..],
        );
        self.pos = Some(pos + self.row_bytes as u64);
        Ok(())
    }

    /// Writes the header and renames header and data into place.
    pub fn finish(mut self) -> Result<(), EnviError> {
        self.flush_line()?;
        self.flush_pending()?;
        let mut hdr = TempFile::create(&self.hdr_path)
            .map_err(|e| EnviErrorKind::io("cannot create header", e).at(&self.hdr_path))?;
        hdr.write_all(self.header.to_text().as_bytes())
            .map_err(|e| EnviErrorKind::io("cannot write header", e).at(&self.hdr_path))?;
        let data_path = self.data_path;
        self.data
            .persist()
            .map_err(|e| EnviErrorKind::io("cannot write data", e).at(&data_path))?;
        hdr.persist()
            .map_err(|e| EnviErrorKind::io("cannot write header", e).at(&self.hdr_path))
    }

    /// `bip`: makes `line` the cached line, writing back the previous one.
    fn load_line(&mut self, line: usize) -> Result<(), EnviError> {
        if self.cached_line == Some(line) {
            return Ok(());
        }
        self.flush_line()?;
        self.flush_pending()?;
        self.cached_line = None;
        let offset = line as u64 * self.line.len() as u64;
        let pos = self.header.header_offset + offset;
        self.seek_to(pos)?;
        self.pos = None;
        self.data
            .file_mut()
            .read_exact(&mut self.line)
            .map_err(|e| EnviErrorKind::io("cannot read back data", e).at(&self.data_path))?;
        self.pos = Some(pos + self.line.len() as u64);
        self.cached_line = Some(line);
        Ok(())
    }

    /// `bip`: writes the cached line back if it changed.
    fn flush_line(&mut self) -> Result<(), EnviError> {
        if let (Some(line), true) = (self.cached_line, self.dirty) {
            let offset = line as u64 * self.line.len() as u64;
            let buf = std::mem::take(&mut self.line);
            let written = self.write_at(offset, &buf);
            self.line = buf;
            written?;
            self.dirty = false;
        }
        Ok(())
    }

    fn seek_to(&mut self, pos: u64) -> Result<(), EnviError> {
        if self.pos != Some(pos) {
            self.flush_pending()?;
            self.pos = None;
            self.data
                .seek(SeekFrom::Start(pos))
                .map_err(|e| EnviErrorKind::io("cannot seek in data", e).at(&self.data_path))?;
        }
        Ok(())
    }

    /// Writes `bytes` at data offset `offset` (after the header offset): gathered with the
    /// bytes before them when they continue them and fit in [`PENDING_BYTES`].
    fn write_at(&mut self, offset: u64, bytes: &[u8]) -> Result<(), EnviError> {
        let pos = self.header.header_offset + offset;
        self.seek_to(pos)?;
        if self.pending.len() + bytes.len() > PENDING_BYTES {
            self.flush_pending()?;
        }
        if bytes.len() >= PENDING_BYTES {
            self.pos = None;
            self.data
                .write_all(bytes)
                .map_err(|e| EnviErrorKind::io("cannot write data", e).at(&self.data_path))?;
        } else {
            self.pending.extend_from_slice(bytes);
        }
        self.pos = Some(pos + bytes.len() as u64);
        Ok(())
    }

    /// Writes the gathered bytes where they belong (the file's position is where they
    /// start).
    fn flush_pending(&mut self) -> Result<(), EnviError> {
        if self.pending.is_empty() {
            return Ok(());
        }
        let pending = std::mem::take(&mut self.pending);
        let end = self.pos;
        self.pos = None;
        let written = self.data.write_all(&pending);
        self.pending = pending;
        self.pending.clear();
        written.map_err(|e| EnviErrorKind::io("cannot write data", e).at(&self.data_path))?;
        self.pos = end;
        Ok(())
    }
}

/// Writes a one-band float32 BSQ little-endian map (`NAME.hdr` + `NAME.img`), the form of
/// filmscope's per-pixel outputs.
///
/// `data` is row-major, `samples` values per line, `lines` lines; NaN is written as is
/// (the contract's "no estimate"). `extra_keys` are added to the header verbatim (e.g.
/// `("data ignore value", "nan")`, or `("band names", "{thickness_nm}")`). The files are
/// replaced atomically, as by [`EnviWriter::finish`].
pub fn write_f32_map(
    hdr_path: impl AsRef<Path>,
    samples: usize,
    lines: usize,
    data: &[f32],
    description: Option<&str>,
    extra_keys: &[(&str, &str)],
) -> Result<(), EnviError> {
    let hdr_path = hdr_path.as_ref();
    let expected = samples.checked_mul(lines);
    if expected != Some(data.len()) {
        return Err(EnviErrorKind::MapLength {
            samples,
            lines,
            expected: expected.unwrap_or(usize::MAX),
            got: data.len(),
        }
        .at(hdr_path));
    }
    let mut header = EnviHeader::new(samples, lines, 1, DataType::F32, Interleave::Bsq);
    header.description = description.map(str::to_string);
    header.extra = extra_keys
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    let mut writer = EnviWriter::create(hdr_path, &header)?;
    for (line, row) in data.chunks_exact(samples.max(1)).enumerate() {
        writer.write_band_row(0, line, row)?;
    }
    writer.finish()
}
