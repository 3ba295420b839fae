//! ENVI reading and writing: fixtures written by Spectral Python, round trips through the
//! writer, and bad input that must fail with a one-line message naming the file.
//!
//! The fixtures (tests/fixtures/envi, made by `gen_envi.py`) are 5 samples x 3 lines x 4
//! bands holding `v = 1000*band + 10*line + sample`, stored as `v / 1000` ("milli"), `v`
//! ("counts") or `v - 1500` with a scale factor of 1000 ("signed").

use std::error::Error;
use std::fs;
use std::path::{Path, PathBuf};

use filmscope::io::envi::{
    read_cube, write_f32_map, BandRow, ByteOrder, DataType, EnviHeader, EnviReader, EnviWriter,
    Interleave,
};

type TestResult = Result<(), Box<dyn Error>>;

const SAMPLES: usize = 5;
const LINES: usize = 3;
const BANDS: usize = 4;
const WAVELENGTH_NM: [f64; 4] = [450.0, 500.0, 550.0, 600.0];

#[derive(Clone, Copy, Debug)]
enum Kind {
    Milli,
    Counts,
    Signed,
}

fn v(band: usize, line: usize, sample: usize) -> f64 {
    (1000 * band + 10 * line + sample) as f64
}

fn expected(kind: Kind, band: usize, line: usize, sample: usize) -> f32 {
    let v = v(band, line, sample);
    match kind {
        Kind::Milli => (v / 1000.0) as f32,
        Kind::Counts => v as f32,
        Kind::Signed => ((v - 1500.0) / 1000.0) as f32,
    }
}

struct Fixture {
    name: &'static str,
    interleave: Interleave,
    data_type: DataType,
    byte_order: ByteOrder,
    kind: Kind,
    data_file: &'static str,
    offset: u64,
}

const FIXTURES: &[Fixture] = &[
    Fixture {
        name: "bsq_f32_le",
        interleave: Interleave::Bsq,
        data_type: DataType::F32,
        byte_order: ByteOrder::Little,
        kind: Kind::Milli,
        data_file: "bsq_f32_le.img",
        offset: 0,
    },
    Fixture {
        name: "bil_u16_le",
        interleave: Interleave::Bil,
        data_type: DataType::U16,
        byte_order: ByteOrder::Little,
        kind: Kind::Counts,
        data_file: "bil_u16_le.img",
        offset: 0,
    },
    Fixture {
        name: "bip_i16_be",
        interleave: Interleave::Bip,
        data_type: DataType::I16,
        byte_order: ByteOrder::Big,
        kind: Kind::Signed,
        data_file: "bip_i16_be.img",
        offset: 0,
    },
    Fixture {
        name: "bsq_f64_be",
        interleave: Interleave::Bsq,
        data_type: DataType::F64,
        byte_order: ByteOrder::Big,
        kind: Kind::Milli,
        data_file: "bsq_f64_be.dat",
        offset: 0,
    },
    Fixture {
        name: "bil_f32_be",
        interleave: Interleave::Bil,
        data_type: DataType::F32,
        byte_order: ByteOrder::Big,
        kind: Kind::Milli,
        data_file: "bil_f32_be.raw",
        offset: 0,
    },
    Fixture {
        name: "bip_f32_le",
        interleave: Interleave::Bip,
        data_type: DataType::F32,
        byte_order: ByteOrder::Little,
        kind: Kind::Milli,
        data_file: "bip_f32_le",
        offset: 0,
    },
    Fixture {
        name: "bsq_u16_unitless_um",
        interleave: Interleave::Bsq,
        data_type: DataType::U16,
        byte_order: ByteOrder::Little,
        kind: Kind::Counts,
        data_file: "bsq_u16_unitless_um.img",
        offset: 0,
    },
    Fixture {
        name: "bil_u16_offset",
        interleave: Interleave::Bil,
        data_type: DataType::U16,
        byte_order: ByteOrder::Little,
        kind: Kind::Counts,
        data_file: "bil_u16_offset.img",
        offset: 64,
    },
    Fixture {
        name: "bil_f32_titlecase",
        interleave: Interleave::Bil,
        data_type: DataType::F32,
        byte_order: ByteOrder::Little,
        kind: Kind::Milli,
        data_file: "bil_f32_titlecase.img",
        offset: 0,
    },
];

fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/envi")
}

/// The (band, line) sequence `next_band_row` must produce for `interleave`.
fn native_order(interleave: Interleave, lines: usize, bands: usize) -> Vec<BandRow> {
    let mut out = Vec::new();
    match interleave {
        Interleave::Bsq => {
            for band in 0..bands {
                for line in 0..lines {
                    out.push(BandRow { band, line });
                }
            }
        }
        Interleave::Bil | Interleave::Bip => {
            for line in 0..lines {
                for band in 0..bands {
                    out.push(BandRow { band, line });
                }
            }
        }
    }
    out
}

fn assert_close(got: Option<&Vec<f64>>, want: &[f64], what: &str) {
    let got = got.map(Vec::as_slice).unwrap_or_default();
    assert_eq!(got.len(), want.len(), "{what}: {got:?}");
    for (g, w) in got.iter().zip(want) {
        assert!((g - w).abs() < 1e-9, "{what}: {got:?} vs {want:?}");
    }
}

#[test]
fn spectral_fixtures_read_every_value_streamed_random_and_whole() -> TestResult {
    for f in FIXTURES {
        let hdr = fixture_dir().join(format!("{}.hdr", f.name));
        let mut reader = EnviReader::open(&hdr)?;
        let h = reader.header().clone();
        assert_eq!(
            (h.samples, h.lines, h.bands),
            (SAMPLES, LINES, BANDS),
            "{}",
            f.name
        );
        assert_eq!(h.interleave, f.interleave, "{}", f.name);
        assert_eq!(h.data_type, f.data_type, "{}", f.name);
        assert_eq!(h.byte_order, f.byte_order, "{}", f.name);
        assert_eq!(h.header_offset, f.offset, "{}", f.name);
        assert_close(h.wavelength_nm.as_ref(), &WAVELENGTH_NM, f.name);
        assert_eq!(
            reader.data_path().file_name(),
            Some(std::ffi::OsStr::new(f.data_file)),
            "{}",
            f.name
        );

        // Streamed, in the file's native order.
        let mut row = vec![f32::NAN; SAMPLES];
        let mut seen = Vec::new();
        while let Some(r) = reader.next_band_row(&mut row)? {
            for (s, &got) in row.iter().enumerate() {
                assert_eq!(got, expected(f.kind, r.band, r.line, s), "{} {r}", f.name);
            }
            seen.push(r);
        }
        assert_eq!(seen, native_order(f.interleave, LINES, BANDS), "{}", f.name);
        assert_eq!(reader.next_band_row(&mut row)?, None);

        // Random access, in an order unlike any interleave.
        for i in 0..LINES * BANDS {
            let k = (i * 7 + 3) % (LINES * BANDS);
            let (band, line) = (k % BANDS, k / BANDS);
            reader.read_band_row(band, line, &mut row)?;
            for (s, &got) in row.iter().enumerate() {
                assert_eq!(got, expected(f.kind, band, line, s), "{} random", f.name);
            }
        }

        // Whole cube.
        let cube = read_cube(&hdr)?;
        assert_eq!(
            (cube.samples, cube.lines, cube.bands),
            (SAMPLES, LINES, BANDS)
        );
        for band in 0..BANDS {
            for line in 0..LINES {
                for s in 0..SAMPLES {
                    assert_eq!(
                        cube.get(band, line, s),
                        Some(expected(f.kind, band, line, s))
                    );
                }
            }
        }
        assert_eq!(cube.get(BANDS, 0, 0), None);
    }
    Ok(())
}

#[test]
fn fixture_headers_keep_units_case_and_extra_keys() -> TestResult {
    let h = EnviHeader::read(&fixture_dir().join("bil_u16_le.hdr"))?;
    assert_close(h.fwhm_nm.as_ref(), &[10.0, 10.0, 12.5, 12.5], "fwhm um");
    let h = EnviHeader::read(&fixture_dir().join("bip_i16_be.hdr"))?;
    assert_eq!(h.reflectance_scale_factor, Some(1000.0));
    let h = EnviHeader::read(&fixture_dir().join("bil_f32_titlecase.hdr"))?;
    assert!(h
        .extra
        .iter()
        .any(|(k, v)| k == "sensor type" && v == "LCTF"));
    assert_eq!(
        h.description.as_deref(),
        Some("filmscope fixture bil_f32_titlecase: milli")
    );
    Ok(())
}

#[test]
fn streaming_survives_interleaved_random_reads() -> TestResult {
    for name in ["bsq_f32_le", "bil_f32_be", "bip_f32_le"] {
        let mut reader = EnviReader::open(fixture_dir().join(format!("{name}.hdr")))?;
        let mut row = vec![0.0; SAMPLES];
        let mut scratch = vec![0.0; SAMPLES];
        while let Some(r) = reader.next_band_row(&mut row)? {
            assert_eq!(
                row[1],
                expected(Kind::Milli, r.band, r.line, 1),
                "{name} {r}"
            );
            reader.read_band_row(BANDS - 1 - r.band, LINES - 1 - r.line, &mut scratch)?;
            assert_eq!(
                scratch[2],
                expected(Kind::Milli, BANDS - 1 - r.band, LINES - 1 - r.line, 2)
            );
        }
        assert_eq!(reader.rows_read(), LINES * BANDS);
        reader.rewind();
        assert_eq!(
            reader.next_band_row(&mut row)?,
            Some(BandRow { band: 0, line: 0 })
        );
    }
    Ok(())
}

/// A cube of `samples x lines x bands` with distinct values, BSQ order.
fn pattern(samples: usize, lines: usize, bands: usize) -> Vec<f32> {
    let mut data = Vec::with_capacity(samples * lines * bands);
    for band in 0..bands {
        for line in 0..lines {
            for s in 0..samples {
                data.push((band * 10_000 + line * 100 + s) as f32 / 64.0);
            }
        }
    }
    data
}

fn write_cube(hdr: &Path, header: &EnviHeader, data: &[f32]) -> TestResult {
    let (samples, lines, bands) = (header.samples, header.lines, header.bands);
    let mut writer = EnviWriter::create(hdr, header)?;
    // Rows in an order unlike any interleave: lines backwards, bands interleaved.
    for line in (0..lines).rev() {
        for band in (0..bands).step_by(2).chain((1..bands).step_by(2)) {
            let start = (band * lines + line) * samples;
            writer.write_band_row(band, line, &data[start..start + samples])?;
        }
    }
    writer.finish()?;
    Ok(())
}

#[test]
fn writer_round_trips_every_interleave_type_and_byte_order() -> TestResult {
    let dir = tempfile::tempdir()?;
    let (samples, lines, bands) = (7, 4, 3);
    let data = pattern(samples, lines, bands);
    for interleave in [Interleave::Bsq, Interleave::Bil, Interleave::Bip] {
        for data_type in [DataType::F32, DataType::U16] {
            for byte_order in [ByteOrder::Little, ByteOrder::Big] {
                let mut header = EnviHeader::new(samples, lines, bands, data_type, interleave);
                header.byte_order = byte_order;
                header.wavelength_nm = Some(vec![500.0, 550.0, 600.0]);
                header.fwhm_nm = Some(vec![8.0, 8.0, 9.0]);
                header.description = Some("round trip".to_string());
                // uint16 stores value * 64 exactly (all pattern values are k / 64).
                if data_type == DataType::U16 {
                    header.reflectance_scale_factor = Some(64.0);
                }
                let name = format!(
                    "{}_{}_{}.hdr",
                    interleave.name(),
                    data_type.name(),
                    byte_order.code()
                );
                let hdr = dir.path().join(&name);
                write_cube(&hdr, &header, &data)?;
                let cube = read_cube(&hdr)?;
                assert_eq!(cube.header, header, "{name}");
                assert_eq!(cube.data, data, "{name}");
            }
        }
    }
    let leftovers: Vec<_> = fs::read_dir(dir.path())?
        .filter_map(Result::ok)
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    Ok(())
}

#[test]
fn bil_stream_matches_bsq_and_bip_of_the_same_cube() -> TestResult {
    let dir = tempfile::tempdir()?;
    let (samples, lines, bands) = (33, 9, 6);
    let data = pattern(samples, lines, bands);
    let mut rows = Vec::new();
    for interleave in [Interleave::Bsq, Interleave::Bil, Interleave::Bip] {
        let hdr = dir.path().join(format!("c_{}.hdr", interleave.name()));
        let header = EnviHeader::new(samples, lines, bands, DataType::F32, interleave);
        write_cube(&hdr, &header, &data)?;
        let mut reader = EnviReader::open(&hdr)?;
        let mut row = vec![0.0; samples];
        let mut by_position = vec![Vec::new(); lines * bands];
        while let Some(r) = reader.next_band_row(&mut row)? {
            by_position[r.band * lines + r.line] = row.clone();
        }
        rows.push(by_position);
    }
    assert_eq!(rows[0], rows[1]);
    assert_eq!(rows[0], rows[2]);
    Ok(())
}

#[test]
fn f32_map_round_trips_nan() -> TestResult {
    let dir = tempfile::tempdir()?;
    let hdr = dir.path().join("thickness_nm.hdr");
    let (samples, lines) = (6, 4);
    let data: Vec<f32> = (0..samples * lines)
        .map(|i| {
            if i % 5 == 0 {
                f32::NAN
            } else {
                i as f32 * 12.5
            }
        })
        .collect();
    write_f32_map(
        &hdr,
        samples,
        lines,
        &data,
        Some("film thickness, nm"),
        &[
            ("band names", "{thickness_nm}"),
            ("data ignore value", "nan"),
        ],
    )?;
    let cube = read_cube(&hdr)?;
    assert_eq!(cube.header.interleave, Interleave::Bsq);
    assert_eq!(cube.header.data_type, DataType::F32);
    assert_eq!(cube.header.byte_order, ByteOrder::Little);
    assert_eq!(cube.bands, 1);
    assert_eq!(
        cube.header.description.as_deref(),
        Some("film thickness, nm")
    );
    assert!(cube
        .header
        .extra
        .contains(&("band names".to_string(), "{thickness_nm}".to_string())));
    let bits = |d: &[f32]| d.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&cube.data), bits(&data));
    assert_eq!(fs::metadata(dir.path().join("thickness_nm.img"))?.len(), 96);

    // Overwriting replaces both files.
    write_f32_map(&hdr, 2, 1, &[1.0, 2.0], None, &[])?;
    assert_eq!(read_cube(&hdr)?.data, vec![1.0, 2.0]);

    // A length mismatch is an error, not a panic.
    let err = write_f32_map(&hdr, 3, 3, &[1.0], None, &[])
        .err()
        .ok_or("short map accepted")?;
    assert!(err.to_string().contains("thickness_nm.hdr"), "{err}");
    Ok(())
}

#[test]
fn unfinished_writer_leaves_old_files_and_no_temporaries() -> TestResult {
    let dir = tempfile::tempdir()?;
    let hdr = dir.path().join("map.hdr");
    write_f32_map(&hdr, 2, 2, &[1.0, 2.0, 3.0, 4.0], None, &[])?;
    {
        let header = EnviHeader::new(2, 2, 1, DataType::F32, Interleave::Bsq);
        let mut writer = EnviWriter::create(&hdr, &header)?;
        writer.write_band_row(0, 0, &[9.0, 9.0])?;
        // Dropped without finish: as if the process died.
    }
    assert_eq!(read_cube(&hdr)?.data, vec![1.0, 2.0, 3.0, 4.0]);
    let names: Vec<String> = fs::read_dir(dir.path())?
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 2, "{names:?}");
    Ok(())
}

#[test]
fn writer_rejects_misuse_without_panicking() -> TestResult {
    let dir = tempfile::tempdir()?;
    let header = EnviHeader::new(4, 2, 2, DataType::F32, Interleave::Bip);
    let mut writer = EnviWriter::create(dir.path().join("w.hdr"), &header)?;
    assert!(writer.write_band_row(2, 0, &[0.0; 4]).is_err());
    assert!(writer.write_band_row(0, 2, &[0.0; 4]).is_err());
    assert!(writer.write_band_row(0, 0, &[0.0; 3]).is_err());
    let f64_header = EnviHeader::new(4, 2, 2, DataType::F64, Interleave::Bsq);
    let err = EnviWriter::create(dir.path().join("x.hdr"), &f64_header)
        .err()
        .ok_or("float64 writer accepted")?;
    assert!(err.to_string().contains("x.hdr"), "{err}");
    assert!(EnviWriter::create(dir.path().join("x.img"), &header).is_err());
    let mut bad = header.clone();
    bad.wavelength_nm = Some(vec![500.0]);
    assert!(EnviWriter::create(dir.path().join("y.hdr"), &bad).is_err());
    Ok(())
}

const GOOD_HEADER: &str =
    "ENVI\nsamples = 4\nlines = 2\nbands = 3\nheader offset = 0\ndata type = 4\ninterleave = bil\nbyte order = 0\n";

/// Writes `NAME.hdr` with `header` and, if given, `NAME.img` with `data_len` zero bytes.
fn make(
    dir: &Path,
    name: &str,
    header: &[u8],
    data_len: Option<usize>,
) -> std::io::Result<PathBuf> {
    let hdr = dir.join(format!("{name}.hdr"));
    fs::write(&hdr, header)?;
    if let Some(len) = data_len {
        fs::write(dir.join(format!("{name}.img")), vec![0u8; len])?;
    }
    Ok(hdr)
}

/// Opens `hdr` expecting an error whose one-line message names `file` and says `want`.
fn expect_error(hdr: &Path, file: &str, want: &str) {
    match EnviReader::open(hdr) {
        Ok(r) => panic!("{} opened: {:?}", hdr.display(), r.header()),
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.contains('\n'), "multi-line: {msg:?}");
            assert!(msg.contains(file), "{msg:?} does not name {file}");
            assert!(msg.contains(want), "{msg:?} lacks {want:?}");
        }
    }
    assert!(read_cube(hdr).is_err());
}

#[test]
fn size_mismatch_message_matches_the_contract_example() -> TestResult {
    let dir = tempfile::tempdir()?;
    let hdr = make(
        dir.path(),
        "a10",
        b"ENVI\nsamples = 64\nlines = 32\nbands = 3\ndata type = 4\ninterleave = bil\n",
        Some(1200),
    )?;
    let err = EnviReader::open(&hdr).err().ok_or("opened")?;
    let msg = err.to_string();
    assert!(
        msg.ends_with(
            "a10.img: data is 1200 bytes but a10.hdr declares 64x32x3 float32 (24576 bytes)"
        ),
        "{msg}"
    );
    assert_eq!(err.path(), dir.path().join("a10.img"));
    Ok(())
}

#[test]
fn bad_input_fails_with_a_message_naming_the_file() -> TestResult {
    let dir = tempfile::tempdir()?;
    let d = dir.path();
    let good = GOOD_HEADER.as_bytes();
    let with = |extra: &str| format!("{GOOD_HEADER}{extra}").into_bytes();
    let replace = |from: &str, to: &str| GOOD_HEADER.replace(from, to).into_bytes();

    expect_error(
        &make(d, "nodata", good, None)?,
        "nodata.hdr",
        "no data file found",
    );
    expect_error(
        &make(d, "short", good, Some(95))?,
        "short.img",
        "data is 95 bytes",
    );
    expect_error(
        &make(d, "long", good, Some(97))?,
        "long.img",
        "data is 97 bytes",
    );
    expect_error(
        &make(d, "empty_data", good, Some(0))?,
        "empty_data.img",
        "data is 0 bytes",
    );
    expect_error(
        &make(
            d,
            "offset",
            &replace("header offset = 0", "header offset = 8"),
            Some(96),
        )?,
        "offset.img",
        "after a 8-byte header offset (104 bytes)",
    );
    expect_error(
        &make(
            d,
            "dtype",
            &replace("data type = 4", "data type = 1"),
            Some(96),
        )?,
        "dtype.hdr",
        "data type 1 (uint8) is not supported",
    );
    expect_error(
        &make(
            d,
            "dtype_text",
            &replace("data type = 4", "data type = float"),
            Some(96),
        )?,
        "dtype_text.hdr",
        "data type float is not supported",
    );
    expect_error(
        &make(
            d,
            "inter",
            &replace("interleave = bil", "interleave = bsp"),
            Some(96),
        )?,
        "inter.hdr",
        "unknown interleave `bsp`",
    );
    expect_error(
        &make(d, "wl", &with("wavelength = { 500, 600 }\n"), Some(96))?,
        "wl.hdr",
        "`wavelength` lists 2 values but `bands` is 3",
    );
    expect_error(
        &make(d, "fw", &with("fwhm = {\n 5,\n 5,\n 5,\n 5 }\n"), Some(96))?,
        "fw.hdr",
        "`fwhm` lists 4 values but `bands` is 3",
    );
    expect_error(
        &make(
            d,
            "garbage",
            &[0xff, 0xfe, 0x00, 0x13, 0x37, b'\n', 0x80],
            Some(96),
        )?,
        "garbage.hdr",
        "not an ENVI header",
    );
    expect_error(
        &make(d, "prose", b"hello = world\nsamples = 4\n", Some(96))?,
        "prose.hdr",
        "not an ENVI header",
    );
    expect_error(&make(d, "empty", b"", Some(96))?, "empty.hdr", "empty file");
    expect_error(
        &make(d, "blank", b"ENVI\n", Some(96))?,
        "blank.hdr",
        "missing required key `samples`",
    );
    expect_error(
        &make(d, "unclosed", &with("wavelength = { 500, 600,\n"), Some(96))?,
        "unclosed.hdr",
        "never closed",
    );
    expect_error(
        &make(d, "zero", &replace("lines = 2", "lines = 0"), Some(0))?,
        "zero.hdr",
        "`lines` must be positive",
    );
    expect_error(
        &make(d, "neg", &replace("bands = 3", "bands = -3"), Some(96))?,
        "neg.hdr",
        "`bands = -3`",
    );
    expect_error(
        &make(
            d,
            "units",
            &with("wavelength units = wavenumber\n"),
            Some(96),
        )?,
        "units.hdr",
        "unsupported wavelength units",
    );
    // Huge declared sizes: must be refused from the file size, never allocated.
    expect_error(
        &make(
            d,
            "huge",
            &replace("samples = 4", "samples = 1000000000000"),
            Some(96),
        )?,
        "huge.img",
        "declares 1000000000000x2x3 float32 (24000000000000 bytes)",
    );
    expect_error(
        &make(
            d,
            "overflow",
            &replace(
                "samples = 4\nlines = 2",
                "samples = 1000000000000\nlines = 1000000000000",
            ),
            Some(96),
        )?,
        "overflow.hdr",
        "overflows",
    );
    expect_error(
        &make(
            d,
            "toobig",
            &replace("samples = 4", "samples = 99999999999999999999999"),
            Some(96),
        )?,
        "toobig.hdr",
        "expected a non-negative integer",
    );
    expect_error(&d.join("absent.hdr"), "absent.hdr", "cannot open header");
    fs::write(d.join("notheader.img"), [0u8; 4])?;
    expect_error(
        &d.join("notheader.img"),
        "notheader.img",
        "ending in `.hdr`",
    );
    Ok(())
}

#[test]
fn reader_rejects_misuse_without_panicking() -> TestResult {
    let mut reader = EnviReader::open(fixture_dir().join("bsq_f32_le.hdr"))?;
    let mut short = vec![0.0; SAMPLES - 1];
    assert!(reader.next_band_row(&mut short).is_err());
    let mut row = vec![0.0; SAMPLES];
    assert!(reader.read_band_row(BANDS, 0, &mut row).is_err());
    assert!(reader.read_band_row(0, LINES, &mut row).is_err());
    let err = reader.read_band_row(0, 99, &mut row).err().ok_or("read")?;
    assert!(err.to_string().contains("bsq_f32_le.img"), "{err}");
    Ok(())
}

#[test]
fn data_truncated_after_open_is_an_error() -> TestResult {
    let dir = tempfile::tempdir()?;
    let hdr = make(dir.path(), "t", GOOD_HEADER.as_bytes(), Some(96))?;
    let mut reader = EnviReader::open(&hdr)?;
    fs::write(dir.path().join("t.img"), [0u8; 10])?;
    let mut row = vec![0.0; 4];
    let mut result = Ok(None);
    for _ in 0..6 {
        result = reader.next_band_row(&mut row);
        if result.is_err() {
            break;
        }
    }
    let err = result.err().ok_or("truncated data read")?;
    assert!(err.to_string().contains("t.img: cannot read data"), "{err}");
    Ok(())
}

/// Spectral Python (an independent ENVI reader) opens what filmscope's writer writes: a map
/// and a cube in each interleave, float and scaled u16, checked value by value by
/// `tests/fixtures/envi/check_with_spectral.py`. Skipped, with a note, where `python3` cannot
/// import `spectral` and NumPy, unless `FILMSCOPE_REQUIRE_PEERS` is set (`.ci/run` installs
/// them and sets it).
#[test]
fn spectral_python_opens_what_filmscope_writes() -> TestResult {
    let has_spectral = std::process::Command::new("python3")
        .args(["-c", "import numpy, spectral"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !has_spectral {
        let why = "skipped: python3 cannot import numpy and spectral";
        assert!(
            std::env::var_os("FILMSCOPE_REQUIRE_PEERS").is_none(),
            "{why}"
        );
        eprintln!("{why}");
        return Ok(());
    }
    let tmp = tempfile::tempdir()?;
    let dir = tmp.path().to_path_buf();
    let (samples, lines) = (6, 4);
    let map: Vec<f32> = (0..samples * lines)
        .map(|i| {
            if (i / samples + i % samples) % 3 == 0 {
                f32::NAN
            } else {
                i as f32 * 0.5
            }
        })
        .collect();
    write_f32_map(
        dir.join("map.hdr"),
        samples,
        lines,
        &map,
        Some("check map"),
        &[],
    )?;
    let data = pattern(SAMPLES, LINES, BANDS);
    for interleave in [Interleave::Bsq, Interleave::Bil, Interleave::Bip] {
        let mut header = EnviHeader::new(SAMPLES, LINES, BANDS, DataType::F32, interleave);
        header.wavelength_nm = Some(WAVELENGTH_NM.to_vec());
        write_cube(
            &dir.join(format!("cube_{}.hdr", interleave.name())),
            &header,
            &data,
        )?;
    }
    let mut header = EnviHeader::new(SAMPLES, LINES, BANDS, DataType::U16, Interleave::Bil);
    header.reflectance_scale_factor = Some(64.0);
    write_cube(&dir.join("cube_u16.hdr"), &header, &data)?;
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/envi/check_with_spectral.py"
    );
    let out = std::process::Command::new("python3")
        .arg(script)
        .arg(&dir)
        .output()?;
    assert!(
        out.status.success(),
        "check_with_spectral.py failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    Ok(())
}
