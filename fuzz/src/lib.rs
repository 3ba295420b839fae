//! Fuzzing on the stable toolchain: a seeded mutator over small seed corpora and one target
//! per untrusted-input parser (the ENVI header, capture.toml, inspection recipes, the
//! camera-link receiver, the device reply parsers). A target panics on a bug (a panic inside the parser, or a broken
//! round trip); the driver (`src/main.rs`) catches it and saves the input.
//!
//! Every saved crash and every seed is replayed by `tests/regressions.rs`, so a crash, once
//! fixed, stays fixed.

use std::io::{Read, Write};
use std::path::Path;

use filmscope::io::{Capture, EnviHeader};
use filmscope::line::recipe::Recipe;
use filmscope::rig::CamLink;
use filmscope_core::hw::{FrameKind, FrameRequest, LineCamera, LineEvent};
use filmscope_core::proto::{fscl, kurios, sxwheel, zaber};

/// One fuzz target: a name (also its corpus folder), the function under test and a
/// dictionary of tokens the mutator may insert.
pub struct Target {
    /// Name, as given on the command line and used for `corpus/NAME` and `crashes/NAME-*`.
    pub name: &'static str,
    /// Runs one input; returns whether the input was accepted (accepted inputs join the
    /// mutation pool). Panics on a bug.
    pub run: fn(&[u8]) -> bool,
    /// Tokens worth inserting.
    pub dict: &'static [&'static str],
}

/// Every target.
pub const TARGETS: &[Target] = &[
    Target {
        name: "envi_header",
        run: envi_header,
        dict: &[
            "ENVI\n",
            "samples = ",
            "lines = ",
            "bands = ",
            "header offset = ",
            "data type = ",
            "interleave = ",
            "byte order = ",
            "wavelength = {",
            "fwhm = {",
            "wavelength units = ",
            "reflectance scale factor = ",
            "description = {",
            "file type = ENVI Standard\n",
            "bsq",
            "bil",
            "bip",
            "Micrometers",
            "Unknown",
            "}",
            "{",
            ",",
            "=",
            "\n",
            "\r\n",
            ";",
            "\u{feff}",
            "18446744073709551615",
            "18446744073709551616",
            "4294967296",
            "-1",
            "0",
            "1e308",
            "1e-320",
            "nan",
            "inf",
            "-0",
            "µm",
        ],
    },
    Target {
        name: "envi_file",
        run: envi_file,
        dict: &[
            "samples = ",
            "lines = ",
            "bands = ",
            "header offset = ",
            "data type = 12",
            "data type = 5",
            "data type = 2",
            "interleave = bsq",
            "interleave = bip",
            "byte order = 1",
            "1000000000000",
            "4611686018427387904",
            "18446744073709551615",
            "\n",
            "\u{0}\u{0}\u{80}\u{7f}",
        ],
    },
    Target {
        name: "capture_toml",
        run: capture_toml,
        dict: &[
            "[sample]\n",
            "[search]\n",
            "[[angle]]\n",
            "substrate_index = ",
            "substrate = \"",
            "ambient_index = ",
            "polarization = ",
            "\"unpolarized\"",
            "index_range = [",
            "thickness_range_nm = [",
            "[lens]\n",
            "horizontal_fov_deg = ",
            "incidence_deg = ",
            "cube = \"",
            "white = \"",
            "dark = \"",
            "white_reflectance = ",
            "../",
            "/",
            "\"",
            "'",
            "]",
            "[",
            "{",
            "}",
            "=",
            ",",
            "\n",
            "nan",
            "inf",
            "-inf",
            "1e308",
            "89.999999",
            "90",
            "-0.0",
            "0",
            "9223372036854775807",
            "true",
            "1979-05-27",
        ],
    },
    Target {
        name: "camlink",
        run: camlink,
        dict: &["FSCL", "\u{1}", "\u{2}", "\u{3}", "\u{4}", "\u{ff}"],
    },
    Target {
        name: "zaber",
        run: zaber_reply,
        dict: &[
            "@",
            "#",
            "!",
            "/",
            ":",
            " ",
            "\r\n",
            "OK",
            "RJ",
            "IDLE",
            "BUSY",
            "--",
            "FF",
            "WR",
            "01",
            "1",
            "0",
            "255",
            "256",
            "BADCOMMAND",
            "é",
            "00",
        ],
    },
    Target {
        name: "kurios",
        run: kurios_reply,
        dict: &[
            ">",
            "=",
            "WL",
            "WL=",
            "OM",
            "OM=",
            "CMD_NOT_DEFINED",
            "CMD_ARG_INVALID",
            "\r",
            "Kurios",
            "nan",
            "1e999",
            "-",
            "é",
            "\u{0}",
        ],
    },
    Target {
        name: "sxwheel",
        run: sxwheel_report,
        dict: &["\u{0}", "\u{1}", "\u{ff}"],
    },
    Target {
        name: "recipe_toml",
        run: recipe_toml,
        dict: &[
            "film = \"",
            "[index]\n",
            "[thickness]\n",
            "[acceptance]\n",
            "[[roi]]\n",
            "[spc]\n",
            "[retention]\n",
            "[mqtt]\n",
            "[status]\n",
            "nominal = ",
            "tolerance = ",
            "mode = \"hold\"",
            "tolerance_percent = ",
            "tolerance_nm = ",
            "raw = \"every_nth\"",
            "every_n = ",
            "width = ",
            "-1",
            "1e400",
            "nan",
            "inf",
            "\"",
            "é",
            "\n",
            "=",
        ],
    },
];

/// The target called `name`.
pub fn target(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

/// ENVI header text: parsing never panics; a header that parses renders to text that parses
/// back to the same header (the rendered text is what the writers put on disk).
fn envi_header(data: &[u8]) -> bool {
    let text = String::from_utf8_lossy(data);
    match EnviHeader::parse(&text) {
        Ok(h) => {
            assert!(h.validate().is_ok(), "parse returned an invalid header");
            assert!(h.file_bytes().is_some());
            let _ = h.shape_text();
            let again = match EnviHeader::parse(&h.to_text()) {
                Ok(again) => again,
                Err(e) => panic!("rendered header does not parse: {e}"),
            };
            assert_eq!(
                (again.samples, again.lines, again.bands, again.header_offset),
                (h.samples, h.lines, h.bands, h.header_offset)
            );
            assert_eq!(
                (again.interleave, again.data_type, again.byte_order),
                (h.interleave, h.data_type, h.byte_order)
            );
            assert_eq!(
                again.wavelength_nm.as_ref().map(Vec::len),
                h.wavelength_nm.as_ref().map(Vec::len)
            );
            assert_eq!(again.extra.len(), h.extra.len(), "extra keys lost");
            true
        }
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.contains('\n'), "multi-line error: {msg:?}");
            false
        }
    }
}

/// An ENVI header and its data file on disk: input = header length (2 bytes, little
/// endian), header text, data bytes. Opening checks the declared size against the file
/// before allocating anything; every row then reads or fails with a message naming a file.
fn envi_file(data: &[u8]) -> bool {
    thread_local! {
        static DIR: std::path::PathBuf = {
            let d = std::env::temp_dir().join(format!("filmscope-fuzz-{}", std::process::id()));
            let _ = std::fs::create_dir_all(&d);
            d
        };
    }
    let (head, rest) = data.split_at(data.len().min(2));
    let n = match head {
        [a, b] => usize::from(u16::from_le_bytes([*a, *b])),
        _ => 0,
    };
    let (text, bytes) = rest.split_at(n.min(rest.len()));
    DIR.with(|dir| {
        let hdr = dir.join("c.hdr");
        let img = dir.join("c.img");
        if std::fs::write(&hdr, text).is_err() || std::fs::write(&img, bytes).is_err() {
            return false;
        }
        let mut reader = match filmscope::io::EnviReader::open(&hdr) {
            Ok(r) => r,
            Err(e) => {
                let msg = e.to_string();
                assert!(!msg.contains('\n'), "multi-line error: {msg:?}");
                assert!(msg.contains("c.hdr") || msg.contains("c.img"), "{msg:?}");
                return false;
            }
        };
        let h = reader.header().clone();
        assert!(h.file_bytes().is_some_and(|b| b <= bytes.len() as u64));
        let mut row = vec![0f32; h.samples];
        let mut rows = 0;
        while let Ok(Some(_)) = reader.next_band_row(&mut row) {
            rows += 1;
            assert!(rows <= reader.rows_total(), "more rows than declared");
        }
        assert_eq!(rows, reader.rows_total());
        let cube = filmscope::io::read_cube(&hdr).expect("a cube that streams also reads whole");
        assert_eq!(cube.data.len(), h.samples * h.lines * h.bands);
        true
    })
}

/// Inspection recipe text: parsing and checks never panic; errors are one line naming the
/// file; an accepted recipe has positive tolerances and judges a sensor without panicking.
fn recipe_toml(data: &[u8]) -> bool {
    let text = String::from_utf8_lossy(data);
    match Recipe::parse(&text, Path::new("/fuzz/recipe.toml")) {
        Ok(r) => {
            assert!(r.index.tolerance > 0.0 && r.thickness.tolerance() > 0.0);
            let _ = r.check_sensor(8, 6);
            let t = vec![r.thickness.nominal_nm as f32; 48];
            let _ = filmscope::line::verdict::judge(&r, 8, 6, &t, r.index.nominal);
            true
        }
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.contains('\n'), "multi-line error: {msg:?}");
            assert!(
                msg.contains("recipe.toml"),
                "{msg:?} does not name the file"
            );
            false
        }
    }
}

/// capture.toml text: parsing and value checks never panic, errors are one line and name
/// the file; an accepted capture writes back text that loads to the same values.
fn capture_toml(data: &[u8]) -> bool {
    let text = String::from_utf8_lossy(data);
    let path = Path::new("/fuzz/capture.toml");
    match Capture::from_toml_str(&text, path) {
        Ok(c) => {
            assert!(!c.angles.is_empty());
            assert!(c
                .angles
                .iter()
                .all(|a| (0.0..90.0).contains(&a.incidence_deg)));
            if let Some(m) = c.fit.model_error {
                assert!((0.0..=0.05).contains(&m), "model error {m}");
            }
            if let Some(f) = c.lens.horizontal_fov_deg {
                assert!(f > 0.0 && f < 180.0, "field of view {f}");
                assert!(c.lens.field_of_view().is_some());
            }
            true
        }
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.contains('\n'), "multi-line error: {msg:?}");
            assert!(
                msg.contains("capture.toml"),
                "{msg:?} does not name the file"
            );
            false
        }
    }
}

/// A camera link replaying `data` (in chunks whose sizes it also takes from the input),
/// timing out when it runs dry; writes (triggers) are accepted and dropped.
struct Replay<'a> {
    data: &'a [u8],
    chunk: usize,
}

impl Read for Replay<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.data.is_empty() {
            return Err(std::io::ErrorKind::TimedOut.into());
        }
        let n = self.chunk.min(buf.len()).min(self.data.len());
        buf[..n].copy_from_slice(&self.data[..n]);
        self.data = &self.data[n..];
        Ok(n)
    }
}

impl Write for Replay<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Turns fuzz bytes into a camera-link byte stream. First byte odd: the rest is the raw
/// stream (exercises resynchronisation and CRC checks). Even: the rest is a list of
/// messages `[kind, flags, seq step, frame id, payload length, payload...]`, framed with
/// valid CRCs (exercises what the receiver does with well-formed but hostile messages).
pub fn camlink_stream(data: &[u8]) -> (usize, Vec<u8>) {
    let Some((&mode, rest)) = data.split_first() else {
        return (1, Vec::new());
    };
    let chunk = usize::from(mode >> 1) + 1;
    if mode & 1 == 1 {
        return (chunk, rest.to_vec());
    }
    let mut out = Vec::new();
    let mut seq = 0u32;
    let mut rest = rest;
    while rest.len() >= 5 {
        let (h, tail) = rest.split_at(5);
        let len = usize::from(h[4]).min(tail.len());
        let (payload, tail) = tail.split_at(len);
        rest = tail;
        let header = fscl::Header {
            kind: h[0] % 6,
            flags: u16::from(h[1] % 4),
            seq,
            frame_id: u64::from(h[3] % 4),
        };
        seq = seq.wrapping_add(u32::from(h[2] % 3));
        let mut buf = vec![0u8; fscl::message_len(payload.len())];
        if let Some(n) = fscl::encode(&mut buf, header, payload) {
            out.extend_from_slice(&buf[..n]);
        }
    }
    (chunk, out)
}

/// The camera-link receiver: a trigger and reads until the frame ends or the link fails.
/// Never panics; every row of an accepted frame is reported exactly once, as a row or lost,
/// at its own index.
fn camlink(data: &[u8]) -> bool {
    let (chunk, bytes) = camlink_stream(data);
    // The frame decoder itself on the raw bytes.
    let mut at = 0;
    while at < bytes.len() {
        let step = match fscl::decode(&bytes[at..], 256) {
            fscl::Decoded::Message {
                payload, consumed, ..
            } => {
                let _ = fscl::Leader::parse(payload);
                let _ = fscl::RowHeader::parse(payload);
                let _ = fscl::Trailer::parse(payload);
                let _ = fscl::Trigger::parse(payload);
                consumed
            }
            fscl::Decoded::BadCrc { consumed } => consumed,
            fscl::Decoded::Garbage { skip } => skip,
            fscl::Decoded::Incomplete { .. } => break,
        };
        assert!(step > 0, "decoder made no progress at byte {at}");
        at += step;
    }
    let mut link = CamLink::new(
        Replay {
            data: &bytes,
            chunk,
        },
        "fuzzcam",
        64,
    );
    let request = FrameRequest {
        kind: FrameKind::Sample,
        angle_deg: 10.0,
        lambda_nm: 550.0,
        band: 0,
    };
    let Ok(info) = link.trigger(request) else {
        return false;
    };
    let mut pixels = vec![0u16; info.width as usize];
    let mut reported = vec![false; info.rows as usize];
    for _ in 0..(info.rows as usize + bytes.len() + 8) {
        match link.read_line(&mut pixels) {
            Ok(LineEvent::Row { row }) => {
                let r = row as usize;
                assert!(r < reported.len(), "row {row} beyond {} rows", info.rows);
                assert!(!reported[r], "row {row} reported twice");
                reported[r] = true;
            }
            Ok(LineEvent::Lost { first, count, .. }) => {
                let (a, b) = (first as usize, first as usize + count as usize);
                assert!(
                    b <= reported.len(),
                    "lost rows {a}..{b} beyond {}",
                    info.rows
                );
                for (r, seen) in reported.iter_mut().enumerate().take(b).skip(a) {
                    assert!(!*seen, "row {r} reported twice");
                    *seen = true;
                }
            }
            Ok(LineEvent::End) => {
                assert!(
                    reported.iter().all(|&r| r),
                    "frame ended with rows unreported"
                );
                return true;
            }
            Err(e) => {
                assert!(!e.to_string().contains('\n'));
                return false;
            }
        }
    }
    panic!("the receiver never ended the frame");
}

/// Zaber ASCII replies and commands: never panic; a parsed reply's warning flag is text.
fn zaber_reply(data: &[u8]) -> bool {
    let line = String::from_utf8_lossy(data);
    let _ = zaber::parse_command(&line);
    match zaber::parse(&line) {
        Ok(zaber::Message::Reply(r)) => {
            let _ = r.fault();
            let _ = r.warning_str();
            true
        }
        Ok(_) => true,
        Err(_) => false,
    }
}

/// Kurios replies: never panic.
fn kurios_reply(data: &[u8]) -> bool {
    let line = String::from_utf8_lossy(data);
    let _ = kurios::is_refusal(&line);
    let mut ok = kurios::head(&line).is_some();
    for key in ["WL", "OM", "SN", ""] {
        let _ = kurios::value(&line, key);
        ok |= kurios::number(&line, key).is_some_and(f64::is_finite);
    }
    ok
}

/// SX wheel HID reports: never panic (two bytes: checked exhaustively by the regression
/// test as well).
fn sxwheel_report(data: &[u8]) -> bool {
    let mut ok = false;
    for pair in data.chunks_exact(2) {
        let report = [pair[0], pair[1]];
        let _ = sxwheel::status(report);
        ok |= sxwheel::decode_command(report).is_some();
        let _ = sxwheel::select(pair[0]);
    }
    ok
}

/// A small deterministic PRNG (SplitMix64).
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// Seeded.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n > 0`).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}

const INTERESTING: &[u8] = &[
    0, 1, 0x7f, 0x80, 0xff, b'\n', b'\r', b' ', b'=', b'{', b'}', b',', b'-', b'.', b'0', b'9',
    b'"', b'[', b']', b'e',
];

/// Applies 1 to 4 random mutations to `input`: bit flips, interesting bytes, inserts,
/// deletes, duplicated ranges, dictionary tokens, splices with `other`. Keeps the result
/// under `max_len` bytes.
pub fn mutate(rng: &mut Rng, input: &[u8], other: &[u8], dict: &[&str], max_len: usize) -> Vec<u8> {
    let mut v = input.to_vec();
    for _ in 0..1 + rng.below(4) {
        let len = v.len();
        match rng.below(8) {
            0 if len > 0 => {
                let i = rng.below(len);
                v[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = rng.below(len);
                v[i] = INTERESTING[rng.below(INTERESTING.len())];
            }
            2 => {
                let i = rng.below(len + 1);
                let n = 1 + rng.below(8);
                for _ in 0..n {
                    v.insert(i, rng.next_u64() as u8);
                }
            }
            3 if len > 0 => {
                let i = rng.below(len);
                let n = (1 + rng.below(16)).min(len - i);
                v.drain(i..i + n);
            }
            4 if len > 0 => {
                let i = rng.below(len);
                let n = (1 + rng.below(32)).min(len - i);
                let piece = v[i..i + n].to_vec();
                let at = rng.below(len + 1);
                v.splice(at..at, piece);
            }
            5 | 6 if !dict.is_empty() => {
                let token = dict[rng.below(dict.len())].as_bytes();
                let at = rng.below(len + 1);
                if rng.below(2) == 0 || len == 0 {
                    v.splice(at..at, token.iter().copied());
                } else {
                    let end = (at + token.len()).min(len);
                    v.splice(at..end, token.iter().copied());
                }
            }
            _ if !other.is_empty() => {
                let cut = rng.below(len + 1);
                let from = rng.below(other.len());
                v.truncate(cut);
                v.extend_from_slice(&other[from..]);
            }
            _ => {}
        }
    }
    v.truncate(max_len);
    v
}

/// Runs `target` on `input`, catching a panic: `Err(message)` for a crash.
pub fn run_caught(target: &Target, input: &[u8]) -> Result<bool, String> {
    std::panic::catch_unwind(|| (target.run)(input)).map_err(|e| {
        e.downcast_ref::<String>()
            .cloned()
            .or_else(|| e.downcast_ref::<&str>().map(|s| (*s).to_owned()))
            .unwrap_or_else(|| "panic".to_owned())
    })
}
