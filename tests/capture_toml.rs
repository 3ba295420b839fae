//! `capture.toml`: a valid capture loads (from the file or its directory), round-trips
//! through `write_toml`, and every validation rule fails with a one-line message naming
//! the file at fault.

use std::error::Error;
use std::fs;
use std::path::{Path, PathBuf};

use filmscope::io::capture::{Capture, CaptureErrorKind};
use filmscope::io::envi::{DataType, EnviHeader, EnviWriter, Interleave};
use filmscope::optics::Polarization;

type TestResult = Result<(), Box<dyn Error>>;

const WAVELENGTH_NM: [f64; 3] = [500.0, 550.0, 600.0];

/// Writes a cube `NAME.hdr` of the given shape (values 0.5) with the usual wavelengths.
fn cube(
    dir: &Path,
    name: &str,
    samples: usize,
    lines: usize,
    bands: usize,
    data_type: DataType,
) -> TestResult {
    cube_with(dir, name, samples, lines, bands, data_type, |_| {})
}

fn cube_with(
    dir: &Path,
    name: &str,
    samples: usize,
    lines: usize,
    bands: usize,
    data_type: DataType,
    edit: impl FnOnce(&mut EnviHeader),
) -> TestResult {
    let mut header = EnviHeader::new(samples, lines, bands, data_type, Interleave::Bil);
    header.wavelength_nm = Some(WAVELENGTH_NM.iter().copied().cycle().take(bands).collect());
    edit(&mut header);
    let mut writer = EnviWriter::create(dir.join(format!("{name}.hdr")), &header)?;
    let row = vec![0.5; samples];
    for line in 0..lines {
        for band in 0..bands {
            writer.write_band_row(band, line, &row)?;
        }
    }
    writer.finish()?;
    Ok(())
}

/// A directory with cubes a10, a20 (4x3x3 float32), raw20 (uint16), white (4x1x3) and
/// dark (4x3x3).
fn scene() -> Result<tempfile::TempDir, Box<dyn Error>> {
    let dir = tempfile::tempdir()?;
    let d = dir.path();
    cube(d, "a10", 4, 3, 3, DataType::F32)?;
    cube(d, "a20", 4, 3, 3, DataType::F32)?;
    cube(d, "raw20", 4, 3, 3, DataType::U16)?;
    cube(d, "white", 4, 1, 3, DataType::U16)?;
    cube(d, "dark", 4, 3, 3, DataType::U16)?;
    fs::create_dir(d.join("sub"))?;
    cube(d.join("sub").as_path(), "a30", 4, 3, 3, DataType::F32)?;
    Ok(dir)
}

const VALID: &str = r#"
[sample]
ambient_index = 1.0
substrate_index = 1.65
polarization = "p"

[search]
index_range = [1.2, 3.0]
thickness_range_nm = [50.0, 2000.0]

[[angle]]
incidence_deg = 20.0
cube = "raw20.hdr"
white = "white.hdr"
dark = "dark.hdr"
white_reflectance = 0.99

[[angle]]
incidence_deg = 10
cube = "a10.hdr"

[[angle]]
incidence_deg = 30.0
cube = "sub/a30.hdr"
"#;

fn write_capture(dir: &Path, text: &str) -> std::io::Result<PathBuf> {
    let path = dir.join("capture.toml");
    fs::write(&path, text)?;
    Ok(path)
}

#[test]
fn valid_capture_loads_from_file_and_directory() -> TestResult {
    let dir = scene()?;
    let path = write_capture(dir.path(), VALID)?;
    let c = Capture::load(&path)?;
    assert_eq!(c.sample.ambient_index, 1.0);
    assert_eq!(c.sample.substrate_index, 1.65);
    assert_eq!(c.sample.polarization, Polarization::P);
    assert_eq!(c.search.index_range, Some([1.2, 3.0]));
    assert_eq!(c.search.thickness_range_nm, Some([50.0, 2000.0]));
    let degrees: Vec<f64> = c.angles.iter().map(|a| a.incidence_deg).collect();
    assert_eq!(degrees, vec![20.0, 10.0, 30.0], "file order kept");
    assert_eq!(c.angles[0].cube, dir.path().join("raw20.hdr"));
    assert_eq!(c.angles[0].white, Some(dir.path().join("white.hdr")));
    assert_eq!(c.angles[0].white_reflectance, 0.99);
    assert_eq!(c.angles[1].white_reflectance, 1.0);
    assert_eq!(c.angles[2].cube, dir.path().join("sub").join("a30.hdr"));
    assert!(c.unknown_keys.is_empty());

    let info = c.check()?;
    assert_eq!((info.samples, info.lines, info.bands), (4, 3, 3));
    assert_eq!(info.data_type, DataType::U16);
    assert_eq!(info.wavelength_nm, Some(WAVELENGTH_NM.to_vec()));

    let from_dir = Capture::load(dir.path())?;
    assert_eq!(from_dir, c);
    Ok(())
}

#[test]
fn defaults_apply_and_unknown_keys_are_listed_not_rejected() -> TestResult {
    let dir = scene()?;
    let text = r#"
[sample]
substrate_index = 1.52
colour = "clear"
[[angle]]
incidence_deg = 0
cube = "a10.hdr"
[[angle]]
incidence_deg = 45
cube = "a20.hdr"
whte = "white.hdr"
"#;
    let c = Capture::load(write_capture(dir.path(), text)?)?;
    assert_eq!(c.sample.ambient_index, 1.0);
    assert_eq!(c.sample.polarization, Polarization::S);
    assert_eq!(c.search.index_range, None);
    assert_eq!(
        c.unknown_keys,
        vec!["angle[2].whte".to_string(), "sample.colour".to_string()]
    );
    Ok(())
}

#[test]
fn write_toml_round_trips() -> TestResult {
    let dir = scene()?;
    let c = Capture::load(write_capture(dir.path(), VALID)?)?;
    let copy = dir.path().join("copy.toml");
    c.write_toml(&copy)?;
    let text = fs::read_to_string(&copy)?;
    assert!(text.contains("cube = \"sub/a30.hdr\""), "{text}");
    let back = Capture::load(&copy)?;
    assert_eq!(back.sample, c.sample);
    assert_eq!(back.search, c.search);
    assert_eq!(back.angles, c.angles);

    // Into a directory: capture.toml there, paths outside it kept absolute.
    let other = tempfile::tempdir()?;
    c.write_toml(other.path())?;
    let moved = Capture::load(other.path())?;
    assert_eq!(moved.angles, c.angles);
    Ok(())
}

/// Loads `text` as capture.toml in a fresh scene (after `setup`), expecting an error whose
/// one-line message names `file` and contains `want`.
fn expect_error(
    text: &str,
    setup: impl FnOnce(&Path) -> TestResult,
    file: &str,
    want: &str,
) -> TestResult {
    let dir = scene()?;
    setup(dir.path())?;
    let path = write_capture(dir.path(), text)?;
    match Capture::load(&path) {
        Ok(c) => Err(format!("loaded {:?} (wanted {want:?})", c.angles).into()),
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.contains('\n'), "multi-line: {msg:?}");
            assert!(msg.contains(file), "{msg:?} does not name {file}");
            assert!(msg.contains(want), "{msg:?} lacks {want:?}");
            Ok(())
        }
    }
}

fn none(_: &Path) -> TestResult {
    Ok(())
}

/// VALID's text with the angle tables replaced.
fn with_angles(angles: &str) -> String {
    let head = VALID.split("[[angle]]").next().unwrap_or_default();
    format!("{head}{angles}")
}

const TWO: &str = "[[angle]]\nincidence_deg = 10\ncube = \"a10.hdr\"\n[[angle]]\nincidence_deg = 20\ncube = \"a20.hdr\"\n";

#[test]
fn value_errors() -> TestResult {
    expect_error(
        &with_angles(&format!("[fit]\nmodel_error = 0.2\n{TWO}")),
        none,
        "capture.toml",
        "fit.model_error = 0.2: outside 0 to 0.05",
    )?;
    expect_error(
        "[sample]\nsubstrate_index = 1.5\n",
        none,
        "capture.toml",
        "found 0",
    )?;
    expect_error(
        &with_angles(&format!(
            "{TWO}[[angle]]\nincidence_deg = 10.0\ncube = \"a20.hdr\"\n"
        )),
        none,
        "capture.toml",
        "[[angle]] 1 and 3 both have incidence_deg = 10",
    )?;
    for bad in ["90", "-1", "nan", "120.5"] {
        expect_error(
            &with_angles(&TWO.replace("incidence_deg = 20", &format!("incidence_deg = {bad}"))),
            none,
            "capture.toml",
            "is outside [0, 90)",
        )?;
    }
    for bad in ["0", "-1.5", "nan", "inf"] {
        expect_error(
            &VALID.replace(
                "substrate_index = 1.65",
                &format!("substrate_index = {bad}"),
            ),
            none,
            "capture.toml",
            "sample.substrate_index",
        )?;
    }
    expect_error(
        &VALID.replace("substrate_index = 1.65\n", ""),
        none,
        "capture.toml",
        "missing field `substrate_index`",
    )?;
    expect_error(
        &VALID.replace("substrate_index = 1.65", "substrate_index = \"PET\""),
        none,
        "capture.toml: line 4",
        "invalid type",
    )?;
    expect_error("[sample\n", none, "capture.toml: line 1", "")?;
    expect_error(
        &VALID.replace("polarization = \"p\"", "polarization = \"circular\""),
        none,
        "capture.toml",
        "sample.polarization = \"circular\"",
    )?;
    for bad in ["0", "0.0", "-0.5", "1.6", "nan"] {
        expect_error(
            &VALID.replace(
                "white_reflectance = 0.99",
                &format!("white_reflectance = {bad}"),
            ),
            none,
            "capture.toml",
            "white_reflectance",
        )?;
    }
    expect_error(
        &VALID.replace("index_range = [1.2, 3.0]", "index_range = [3.0, 1.2]"),
        none,
        "capture.toml",
        "search.index_range = [3.0, 1.2]",
    )?;
    Ok(())
}

#[test]
fn file_errors() -> TestResult {
    expect_error(
        &with_angles(&TWO.replace("a20.hdr", "missing.hdr")),
        none,
        "capture.toml",
        "cube of [[angle]] 2 not found",
    )?;
    expect_error(
        &with_angles(&TWO.replace(
            "cube = \"a10.hdr\"",
            "cube = \"a10.hdr\"\nwhite = \"nowhite.hdr\"",
        )),
        none,
        "nowhite.hdr",
        "white of [[angle]] 1 not found",
    )?;
    // A cube whose data disagrees with its header: the cube's own message.
    expect_error(
        &with_angles(TWO),
        |d| Ok(fs::write(d.join("a20.img"), [0u8; 7])?),
        "a20.img",
        "data is 7 bytes but a20.hdr declares 4x3x3 float32 (144 bytes)",
    )?;
    for (what, (s, l, b)) in [
        ("samples", (5, 3, 3)),
        ("lines", (4, 2, 3)),
        ("bands", (4, 3, 2)),
    ] {
        expect_error(
            &with_angles(TWO),
            |d| cube(d, "a20", s, l, b, DataType::F32),
            "a20.hdr",
            &format!("{what} differ from a10.hdr"),
        )?;
    }
    expect_error(
        &with_angles(TWO),
        |d| {
            cube_with(d, "a20", 4, 3, 3, DataType::F32, |h| {
                h.wavelength_nm = Some(vec![500.0, 550.0, 650.0])
            })
        },
        "a20.hdr",
        "wavelengths differ from a10.hdr",
    )?;
    expect_error(
        &with_angles(TWO),
        |d| cube_with(d, "a20", 4, 3, 3, DataType::F32, |h| h.wavelength_nm = None),
        "a20.hdr",
        "wavelengths differ",
    )?;
    expect_error(
        &with_angles(&TWO.replace("a20.hdr", "raw20.hdr")),
        none,
        "capture.toml",
        "[[angle]] 2: cube raw20.hdr holds raw counts (data type 12) but has no white reference",
    )?;
    let raw_with = |reference: &str| {
        with_angles(&TWO.replace(
            "cube = \"a20.hdr\"",
            &format!("cube = \"raw20.hdr\"\nwhite = \"white.hdr\"\n{reference}"),
        ))
    };
    expect_error(
        &raw_with(""),
        |d| cube(d, "white", 5, 1, 3, DataType::U16),
        "white.hdr",
        "white reference has samples 5 but its cube raw20.hdr has 4",
    )?;
    expect_error(
        &raw_with(""),
        |d| cube(d, "white", 4, 1, 2, DataType::U16),
        "white.hdr",
        "white reference has bands 2 but its cube raw20.hdr has 3",
    )?;
    expect_error(
        &raw_with(""),
        |d| cube(d, "white", 4, 2, 3, DataType::U16),
        "white.hdr",
        "white reference has lines 2 but its cube raw20.hdr has 3 (a reference may also have 1)",
    )?;
    expect_error(
        &raw_with("dark = \"dark.hdr\""),
        |d| cube(d, "dark", 4, 5, 3, DataType::U16),
        "dark.hdr",
        "dark reference has lines 5 but",
    )?;
    expect_error(
        &raw_with("dark = \"dark.hdr\""),
        |d| cube(d, "dark", 3, 1, 3, DataType::U16),
        "dark.hdr",
        "dark reference has samples 3",
    )?;
    // One-line white and dark references are fine.
    let dir = scene()?;
    cube(dir.path(), "dark", 4, 1, 3, DataType::U16)?;
    Capture::load(write_capture(dir.path(), &raw_with("dark = \"dark.hdr\""))?)?;
    Ok(())
}

#[test]
fn missing_capture_file_names_it() -> TestResult {
    let dir = tempfile::tempdir()?;
    for path in [dir.path().join("capture.toml"), dir.path().to_path_buf()] {
        let err = Capture::load(&path).err().ok_or("loaded nothing")?;
        let msg = err.to_string();
        assert!(msg.contains("capture.toml: cannot open"), "{msg}");
        assert!(matches!(err.kind(), CaptureErrorKind::Io { .. }));
    }
    Ok(())
}
