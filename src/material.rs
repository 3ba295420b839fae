//! Materials as users name them: an index model written as JSON (the `dispersion` object of
//! `summary.json` and `truth.json`), a name from the built-in library
//! ([`filmscope_core::optics::materials`]), or a refractiveindex.info YAML entry; and the
//! estimated index written back as CSV and as such a YAML entry.
//!
//! refractiveindex.info's formulas (lambda in um): formula 1, `n^2 - 1 = C1 + sum_i
//! C_{2i} l^2 / (l^2 - C_{2i+1}^2)`; formula 2, the same with `C_{2i+1}` in place of
//! `C_{2i+1}^2`; formula 5, `n = C1 + sum_i C_{2i} l^C_{2i+1}` (Cauchy with exponents -2 and
//! -4); `tabulated n` and `tabulated nk`, rows `wavelength_um n [k]`, held as the table
//! ([`Dispersion::Table`], interpolated); a formula with a `tabulated k` entry beside it
//! (absorbing: k above [`CLEAR_K`] somewhere over the visible) as a table of the formula's n
//! and the table's k at every nm. A formula this module cannot hold exactly is refused with
//! the reason.

use std::path::{Path, PathBuf};

use filmscope_core::optics::{materials, Dispersion};
use serde::{Deserialize, Serialize};

/// Why a material could not be had: one line each, naming the file, key or entry at fault.
#[derive(Debug, thiserror::Error)]
pub enum MaterialError {
    /// A `dispersion` object or record that does not describe a model: what is wrong.
    #[error("dispersion: {0}")]
    Record(String),
    /// A refractiveindex.info entry that cannot be read or held: the entry and what is wrong.
    #[error("{0}")]
    Entry(String),
    /// A model whose index at 550 nm is not a film's.
    #[error("dispersion: n(550 nm) = {n} is outside 1..5 (or not a number)")]
    IndexAt550 {
        /// The index at 550 nm.
        n: f64,
    },
    /// A model whose index is not finite, or not above the ambient's, somewhere over the
    /// captured band.
    #[error("n({wavelength_nm:.1} nm) = {} (the captured band is {lo_nm:.1}-{hi_nm:.1} nm)", over_band(*n, *ambient))]
    OverBand {
        /// The first wavelength where it fails, nm.
        wavelength_nm: f64,
        /// The index there.
        n: f64,
        /// The ambient's index.
        ambient: f64,
        /// The band's first wavelength, nm.
        lo_nm: f64,
        /// The band's last wavelength, nm.
        hi_nm: f64,
    },
    /// Neither a readable file nor a library name.
    #[error("material {name:?}: neither a refractiveindex.info YAML file nor one of the library's names ({})", materials::NAMES.join(", "))]
    Unknown {
        /// The name given.
        name: String,
    },
    /// A material file that cannot be read or does not hold a material.
    #[error("{}: {problem}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        problem: Box<MaterialError>,
    },
    /// The operating system refused to read a file (in the message, not a source: one
    /// line, said once).
    #[error("cannot read: {0}")]
    Read(std::io::Error),
    /// A FIFO, device or directory where a file was expected.
    #[error("not a regular file")]
    NotAFile,
    /// A file larger than any material's.
    #[error("{bytes} bytes: a material file is at most {max}")]
    TooLarge {
        /// Its size.
        bytes: u64,
        /// The most accepted.
        max: u64,
    },
}

impl From<std::io::Error> for MaterialError {
    fn from(e: std::io::Error) -> Self {
        Self::Read(e)
    }
}

/// What is wrong with the index `n` against the ambient's `ambient`.
fn over_band(n: f64, ambient: f64) -> String {
    if n.is_finite() {
        format!("{n:.4} is not above the ambient's index {ambient:.4}")
    } else {
        format!("{n} is not a number")
    }
}

/// Callers whose own errors are still one line of text take a material's line as it is.
impl From<MaterialError> for String {
    fn from(e: MaterialError) -> Self {
        e.to_string()
    }
}

/// The dispersion described by `value`: a number (a constant index), a library name or a
/// path to a refractiveindex.info YAML file (a string), or an object with `model` =
/// `constant` (`n`), `cauchy` (`a`, `b_um2`, optional `c_um4`), `sellmeier` (optional `a`,
/// default 1; lists `b` and `c_um` of up to three terms), `table` (`rows`, each
/// `[wavelength_um, n, k]`) or `material` (`name`). Other keys
/// (`n_550`, `n_table`, `formula`) are ignored, so `summary.json`'s `dispersion` reads back.
pub fn dispersion_from_json(value: &serde_json::Value) -> Result<Dispersion, MaterialError> {
    use serde_json::Value;
    let record = MaterialError::Record;
    let d = match value {
        Value::Number(n) => Dispersion::constant(n.as_f64().unwrap_or(f64::NAN)),
        Value::String(s) => resolve(s)?,
        Value::Object(o) => {
            let num = |k: &str| -> Result<f64, MaterialError> {
                o.get(k)
                    .and_then(Value::as_f64)
                    .ok_or_else(|| record(format!("`{k}` must be a number")))
            };
            let list = |k: &str| -> Result<Vec<f64>, MaterialError> {
                let not_list = || record(format!("`{k}` must be a list of numbers"));
                let v = o.get(k).and_then(Value::as_array).ok_or_else(not_list)?;
                v.iter().map(|x| x.as_f64().ok_or_else(not_list)).collect()
            };
            match o.get("model").and_then(Value::as_str) {
                Some("constant") => Dispersion::constant(num("n")?),
                Some("cauchy") | Some("cauchy3") => Dispersion::Cauchy {
                    a: num("a")?,
                    b_um2: num("b_um2")?,
                    c_um4: if o.contains_key("c_um4") {
                        num("c_um4")?
                    } else {
                        0.0
                    },
                },
                Some("sellmeier") | Some("sellmeier_constant") => {
                    let a = if o.contains_key("a") { num("a")? } else { 1.0 };
                    sellmeier(a, &list("b")?, &list("c_um")?)?
                }
                Some("table") => {
                    let table: DispersionRecord = serde_json::from_value(value.clone())
                        .map_err(|e| record(format!("table: {e}")))?;
                    table.dispersion()?
                }
                Some("material") => {
                    let name = o
                        .get("name")
                        .and_then(Value::as_str)
                        .ok_or_else(|| record("model \"material\" needs a `name`".into()))?;
                    resolve(name)?
                }
                Some(other) => {
                    return Err(record(format!(
                        "model {other:?}: expected \"constant\", \"cauchy\", \"sellmeier\", \"table\" or \"material\""
                    )))
                }
                None => return Err(record("needs a `model`".into())),
            }
        }
        other => {
            return Err(record(format!(
                "expected a number, a material name or path, or an object, not {other}"
            )))
        }
    };
    check(d)
}

/// A Sellmeier model `n^2 = a + sum b_i l^2 / (l^2 - c_i^2)` of up to three terms.
fn sellmeier(a: f64, b: &[f64], c_um: &[f64]) -> Result<Dispersion, MaterialError> {
    if b.len() != c_um.len() || b.len() > 3 {
        return Err(MaterialError::Record(format!(
            "sellmeier needs as many `b` as `c_um` terms, at most 3 (got {} and {})",
            b.len(),
            c_um.len()
        )));
    }
    let (mut bb, mut cc) = ([0.0; 3], [0.0; 3]);
    bb[..b.len()].copy_from_slice(b);
    cc[..c_um.len()].copy_from_slice(c_um);
    Ok(Dispersion::Sellmeier { a, b: bb, c_um: cc })
}

/// Refuses a model whose index at 550 nm is not finite or outside 1..5.
fn check(d: Dispersion) -> Result<Dispersion, MaterialError> {
    let n = d.index_at(550.0);
    if n.is_finite() && (1.0..=5.0).contains(&n) {
        Ok(d)
    } else {
        Err(MaterialError::IndexAt550 { n })
    }
}

/// Refuses a model whose index is not finite, or not above `ambient`, anywhere over the
/// band from the lowest to the highest of `bands_nm` (each band centre and every nm
/// between): one line naming the first wavelength where it fails.
pub fn check_over_band(
    d: &Dispersion,
    bands_nm: &[f64],
    ambient: f64,
) -> Result<(), MaterialError> {
    let finite = bands_nm.iter().copied().filter(|l| l.is_finite());
    let lo = finite.clone().fold(f64::INFINITY, f64::min);
    let hi = finite.fold(f64::NEG_INFINITY, f64::max);
    if !(lo.is_finite() && hi.is_finite() && lo > 0.0) {
        return Ok(());
    }
    // At most a few thousand points: bands lie within 200..3000 nm.
    let steps = (hi - lo).ceil().clamp(0.0, 10_000.0) as usize;
    let grid = (0..=steps).map(|i| (lo + i as f64).min(hi));
    let mut points: Vec<f64> = grid.chain(bands_nm.iter().copied()).collect();
    points.sort_by(f64::total_cmp);
    for l in points.into_iter().filter(|l| l.is_finite()) {
        let n = d.index_at(l);
        if !(n.is_finite() && n > ambient) {
            return Err(MaterialError::OverBand {
                wavelength_nm: l,
                n,
                ambient,
                lo_nm: lo,
                hi_nm: hi,
            });
        }
    }
    Ok(())
}

/// A material as a command-line option gives it: a number (a constant index), a library
/// name or a refractiveindex.info YAML path.
pub fn from_arg(text: &str) -> Result<Dispersion, MaterialError> {
    match text.trim().parse::<f64>() {
        Ok(n) => check(Dispersion::constant(n)),
        Err(_) => resolve(text.trim()),
    }
}

/// A material by name from the built-in library, or from a refractiveindex.info YAML file
/// at `name_or_path` (any name ending in `.yml` or `.yaml`, or naming an existing file).
pub fn resolve(name_or_path: &str) -> Result<Dispersion, MaterialError> {
    let path = Path::new(name_or_path);
    let is_yaml = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("yml") || e.eq_ignore_ascii_case("yaml"));
    if is_yaml || path.is_file() {
        let in_file = |e: MaterialError| MaterialError::File {
            path: path.to_owned(),
            problem: Box::new(e),
        };
        let text = read_small(path).map_err(in_file)?;
        return from_rii_yaml(&text).and_then(check).map_err(in_file);
    }
    materials::by_name(name_or_path).ok_or_else(|| MaterialError::Unknown {
        name: name_or_path.to_owned(),
    })
}

/// Material files larger than this are refused (the database's largest are a few hundred
/// kilobytes).
const MAX_MATERIAL_BYTES: u64 = 4 << 20;

/// The text of the regular file `path`, refused above [`MAX_MATERIAL_BYTES`].
fn read_small(path: &Path) -> Result<String, MaterialError> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(MaterialError::NotAFile);
    }
    if meta.len() > MAX_MATERIAL_BYTES {
        return Err(MaterialError::TooLarge {
            bytes: meta.len(),
            max: MAX_MATERIAL_BYTES,
        });
    }
    Ok(std::fs::read_to_string(path)?)
}

/// The model's index at each wavelength as CSV: a `wavelength_nm,n` header, one row a
/// wavelength.
pub fn to_csv(d: &Dispersion, wavelengths_nm: &[f64]) -> String {
    let mut s = String::from("wavelength_nm,n\n");
    for &l in wavelengths_nm {
        s.push_str(&format!("{l},{:.9}\n", d.index_at(l)));
    }
    s
}

/// The model as a refractiveindex.info YAML entry valid over `range_nm`: formula 1 for a
/// Sellmeier model, formula 5 for a Cauchy one, `tabulated n` (two rows, the range's ends)
/// for a constant, `tabulated nk` (every row) for a table. `comment` goes into the entry's `COMMENTS`.
///
/// Written line by line in the database's own layout (indented lists, `data: |` blocks, a
/// header comment), which a YAML emitter does not produce; [`from_rii_yaml`] reads it back.
pub fn to_rii_yaml(d: &Dispersion, range_nm: [f64; 2], comment: &str) -> String {
    let range = format!("{} {}", range_nm[0] * 1e-3, range_nm[1] * 1e-3);
    let mut s = String::from("# refractiveindex.info database entry, written by filmscope\n");
    s.push_str("REFERENCES: \"filmscope estimate\"\n");
    // A JSON string is a YAML double-quoted scalar: backslashes and line breaks escaped.
    let comment = serde_json::Value::from(comment.replace('"', "'"));
    s.push_str(&format!("COMMENTS: {comment}\n"));
    s.push_str("DATA:\n");
    match *d {
        Dispersion::Constant { n } => {
            s.push_str("  - type: tabulated n\n    data: |\n");
            for l in range_nm {
                s.push_str(&format!("        {} {n}\n", l * 1e-3));
            }
        }
        Dispersion::Cauchy { a, b_um2, c_um4 } => {
            s.push_str("  - type: formula 5\n");
            s.push_str(&format!("    wavelength_range: {range}\n"));
            s.push_str(&format!("    coefficients: {a} {b_um2} -2 {c_um4} -4\n"));
        }
        Dispersion::Sellmeier { a, b, c_um } => {
            s.push_str("  - type: formula 1\n");
            s.push_str(&format!("    wavelength_range: {range}\n"));
            let mut c = vec![format!("{}", a - 1.0)];
            for (bi, ci) in b.iter().zip(c_um) {
                if *bi != 0.0 {
                    c.push(format!("{bi} {ci}"));
                }
            }
            s.push_str(&format!("    coefficients: {}\n", c.join(" ")));
        }
        Dispersion::Table { rows } => {
            s.push_str("  - type: tabulated nk\n    data: |\n");
            for r in rows {
                s.push_str(&format!("        {} {} {}\n", r[0], r[1], r[2]));
            }
        }
    }
    s
}

/// A refractiveindex.info material file as filmscope reads it: its `DATA` list. The
/// database's other keys (`REFERENCES`, `COMMENTS`, `SPECS`, `CONDITIONS`) are accepted and
/// left unread.
#[derive(Deserialize)]
struct RiiFile {
    /// The entries: formulas and tables of n, tables of k.
    #[serde(rename = "DATA", default)]
    data: Vec<Entry>,
}

/// One `DATA` entry of a refractiveindex.info file: its type and its coefficients or rows.
/// Coefficients, range and rows are YAML text (a single number reads as its text).
#[derive(Deserialize)]
struct Entry {
    /// `formula N`, `tabulated n`, `tabulated nk` or `tabulated k`.
    #[serde(rename = "type", default)]
    kind: String,
    /// A formula's coefficients, numbers separated by blanks.
    #[serde(default)]
    coefficients: Option<String>,
    /// Where a formula holds, `lo hi` in um.
    #[serde(default)]
    wavelength_range: Option<String>,
    /// A table: one row a line, `wavelength_um n`, `wavelength_um k` or `wavelength_um n k`.
    #[serde(default)]
    data: Option<String>,
}

impl Entry {
    /// The numbers of `text`, one a blank-separated word; an error names the entry's type.
    fn numbers(&self, text: &str) -> Result<Vec<f64>, String> {
        text.split_whitespace()
            .map(|x| {
                x.parse::<f64>()
                    .map_err(|_| format!("{:?}: {x:?} is not a number", self.kind))
            })
            .collect()
    }

    /// The formula's coefficients.
    fn coefficients(&self) -> Result<Vec<f64>, String> {
        let text = self
            .coefficients
            .as_deref()
            .ok_or_else(|| format!("{:?} has no coefficients", self.kind))?;
        self.numbers(text)
    }

    /// The table's rows as text: blank lines and `#` lines left out.
    fn rows(&self) -> impl Iterator<Item = &str> {
        let text = self.data.as_deref().unwrap_or("");
        text.lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && !l.starts_with('#'))
    }
}

/// The first `n` (not `k`) entry of a refractiveindex.info YAML file as a [`Dispersion`].
///
/// Reads the file with a YAML parser into its `DATA` list of entries (`type`,
/// `coefficients`, `wavelength_range`, `data`). Formulas 1 and 2 with up to three terms and
/// formula 5 with exponents -2 and -4 (in any order, or absent) are held exactly, formula 4
/// as a Sellmeier model when it is one, else as its three-term Cauchy within
/// [`FORMULA_FIT_TOLERANCE`]; a `tabulated n` or `tabulated nk` table as the table.
pub fn from_rii_yaml(text: &str) -> Result<Dispersion, MaterialError> {
    rii_entries(text).map_err(MaterialError::Entry)
}

/// [`from_rii_yaml`], its problem in words.
fn rii_entries(text: &str) -> Result<Dispersion, String> {
    let file: RiiFile = yaml_serde::from_str(text)
        .map_err(|e| format!("not a refractiveindex.info YAML file: {e}"))?;
    let entries = file.data;
    let entry = entries
        .iter()
        .find(|e| e.kind != "tabulated k")
        .ok_or("no DATA entry with n (expected `DATA:` with `- type: ...`)")?;
    let n = entry_dispersion(entry)?;
    match entries.iter().find(|e| e.kind == "tabulated k") {
        Some(k) if !matches!(n, Dispersion::Table { .. }) => with_extinction(n, k),
        _ => Ok(n),
    }
}

/// A clear material's extinction coefficient: below this over the whole visible a
/// `tabulated k` beside a formula is left out (a glass's 1e-8, light absorbed over metres).
pub const CLEAR_K: f64 = 1e-5;

/// The formula `n` with the `tabulated k` entry `k` beside it: `n` itself when `k` stays under
/// [`CLEAR_K`] over the visible, else a table of both at every nm of the visible.
fn with_extinction(n: Dispersion, k: &Entry) -> Result<Dispersion, String> {
    let rows = table_rows(k, 2)?;
    let k_rows: Vec<[f64; 3]> = rows.iter().map(|r| [r[0], 0.0, r[1]]).collect();
    let k_of = Dispersion::Table {
        rows: intern(k_rows),
    };
    let grid = || (380..=780).map(f64::from);
    if grid().all(|l| k_of.extinction_at(l) < CLEAR_K) {
        return Ok(n);
    }
    let table: Vec<[f64; 3]> = grid()
        .map(|l| [l * 1e-3, n.index_at(l), k_of.extinction_at(l)])
        .collect();
    Ok(Dispersion::Table {
        rows: intern(table),
    })
}

/// The rows of a tabulated entry, `cols` numbers each (`wavelength_um n`, `wavelength_um k` or
/// `wavelength_um n k`): wavelengths positive and increasing, every value finite, n positive
/// and k not negative.
fn table_rows(entry: &Entry, cols: usize) -> Result<Vec<Vec<f64>>, String> {
    let kind = &entry.kind;
    let mut rows: Vec<Vec<f64>> = Vec::new();
    for line in entry.rows() {
        let v = line
            .split_whitespace()
            .map(|x| {
                x.parse::<f64>()
                    .map_err(|_| format!("{kind}: {x:?} is not a number"))
            })
            .collect::<Result<Vec<f64>, String>>()?;
        if v.len() < cols {
            return Err(format!("{kind}: row {line:?} needs {cols} numbers"));
        }
        if !v.iter().all(|x| x.is_finite()) || v[0] <= 0.0 {
            return Err(format!(
                "{kind}: row {line:?} needs a positive wavelength and finite values"
            ));
        }
        if rows.last().is_some_and(|r| r[0] >= v[0]) {
            return Err(format!("{kind}: row {line:?}: wavelengths must increase"));
        }
        rows.push(v[..cols].to_vec());
    }
    if rows.is_empty() {
        return Err(format!("{kind}: no rows"));
    }
    Ok(rows)
}

/// The table `rows` with a `'static` life, as [`Dispersion::Table`] holds it: each distinct
/// table is kept once for the process (a capture, recipe or scene names a few).
pub fn intern(rows: Vec<[f64; 3]>) -> &'static [[f64; 3]] {
    use std::sync::Mutex;
    static TABLES: Mutex<Vec<&'static [[f64; 3]]>> = Mutex::new(Vec::new());
    let mut tables = TABLES.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(t) = tables.iter().find(|t| **t == rows.as_slice()) {
        return t;
    }
    let t: &'static [[f64; 3]] = Box::leak(rows.into_boxed_slice());
    tables.push(t);
    t
}

/// The dispersion of one `DATA` entry with n (a formula or a table).
fn entry_dispersion(entry: &Entry) -> Result<Dispersion, String> {
    match entry.kind.as_str() {
        "formula 1" | "formula 2" => sellmeier_formula(entry),
        "formula 5" => cauchy_formula(entry),
        "formula 4" => formula_4(entry),
        "tabulated n" | "tabulated nk" => tabulated(entry),
        other => Err(format!(
            "DATA type {other:?}: filmscope reads formula 1, 2, 4 and 5, tabulated n and nk (and tabulated k beside a formula)"
        )),
    }
}

/// Formula 1 (`C1` and `(B, C)` pairs) or formula 2 (`(B, C^2)` pairs) as a Sellmeier model.
fn sellmeier_formula(entry: &Entry) -> Result<Dispersion, String> {
    let c = entry.coefficients()?;
    if c.is_empty() || c.len() % 2 == 0 || c.len() > 7 {
        return Err(format!(
            "{}: expected C1 and one to three (B, C) pairs, got {} coefficients",
            entry.kind,
            c.len()
        ));
    }
    let pairs: Vec<(f64, f64)> = c[1..].chunks(2).map(|p| (p[0], p[1])).collect();
    let b: Vec<f64> = pairs.iter().map(|p| p.0).collect();
    let cc: Vec<f64> = if entry.kind == "formula 1" {
        pairs.iter().map(|p| p.1).collect()
    } else {
        pairs.iter().map(|p| p.1.max(0.0).sqrt()).collect()
    };
    sellmeier(1.0 + c[0], &b, &cc).map_err(String::from)
}

/// Formula 5 (`C1` and `(coefficient, exponent)` pairs) as a Cauchy model: exponents -2 and
/// -4 only.
fn cauchy_formula(entry: &Entry) -> Result<Dispersion, String> {
    let c = entry.coefficients()?;
    if c.is_empty() || c.len() % 2 == 0 {
        return Err(format!(
            "formula 5: expected C1 and (coefficient, exponent) pairs, got {} coefficients",
            c.len()
        ));
    }
    let (mut b, mut cc) = (0.0, 0.0);
    for p in c[1..].chunks(2) {
        if p[1] == -2.0 {
            b += p[0];
        } else if p[1] == -4.0 {
            cc += p[0];
        } else {
            let e = p[1];
            return Err(format!(
                "formula 5: exponent {e} (filmscope holds Cauchy terms with exponents -2 and -4 only)"
            ));
        }
    }
    Ok(Dispersion::Cauchy {
        a: c[0],
        b_um2: b,
        c_um4: cc,
    })
}

/// Formula 4, `n^2 = C1 + C2 l^C3 / (l^2 - C4^C5) + C6 l^C7 / (l^2 - C8^C9) + sum C_i
/// l^C_{i+1}`: a Sellmeier model when it is one, else its three-term Cauchy over the
/// visible part of its range (see [`held_within`]).
fn formula_4(entry: &Entry) -> Result<Dispersion, String> {
    let mut c = entry.coefficients()?;
    if c.is_empty() || c.len() > 17 {
        return Err(format!(
            "formula 4: expected 1 to 17 coefficients, got {}",
            c.len()
        ));
    }
    c.resize(17, 0.0);
    let [lo, hi] = visible_part(entry)?;
    if let Some(d) = formula_4_as_sellmeier(&c) {
        return d;
    }
    let rows: Vec<(f64, f64)> = (0..=100)
        .map(|i| {
            let l = lo + (hi - lo) * f64::from(i) / 100.0;
            (l, formula_4_n2(&c, l).max(0.0).sqrt())
        })
        .collect();
    held_within(&rows, "formula 4")
}

/// Formula 4's 17 coefficients `c` as a Sellmeier model, exactly, when its poles have l^0
/// or l^2 over (l^2 - c^2) and it has no power terms (`C l^0 / (l^2 - c^2) = (C / c^2) l^2 /
/// (l^2 - c^2) - C / c^2`); `None` when it is not of that form.
fn formula_4_as_sellmeier(c: &[f64]) -> Option<Result<Dispersion, String>> {
    let no_powers = [9, 11, 13, 15].iter().all(|&k| c[k] == 0.0);
    let poles: Vec<(f64, f64, f64)> = [1, 5]
        .iter()
        .filter(|&&k| c[k] != 0.0)
        .map(|&k| (c[k], c[k + 1], c[k + 2].powf(c[k + 3])))
        .collect();
    let sellmeier_form = poles
        .iter()
        .all(|p| (p.1 == 0.0 || p.1 == 2.0) && p.2 > 0.0);
    if !(no_powers && sellmeier_form) {
        return None;
    }
    let mut a = c[0];
    let (mut b, mut cc) = (Vec::new(), Vec::new());
    for &(strength, power, c2) in &poles {
        let bi = if power == 0.0 {
            strength / c2
        } else {
            strength
        };
        if power == 0.0 {
            a -= bi;
        }
        b.push(bi);
        cc.push(c2.sqrt());
    }
    Some(sellmeier(a, &b, &cc).map_err(String::from))
}

/// Formula 4's n^2 at `l` um, its 17 coefficients `c`.
fn formula_4_n2(c: &[f64], l: f64) -> f64 {
    let pole = |k: usize| {
        if c[k] == 0.0 {
            0.0
        } else {
            c[k] * l.powf(c[k + 1]) / (l * l - c[k + 2].powf(c[k + 3]))
        }
    };
    let power = |k: usize| {
        if c[k] == 0.0 {
            0.0
        } else {
            c[k] * l.powf(c[k + 1])
        }
    };
    c[0] + pole(1) + pole(5) + power(9) + power(11) + power(13) + power(15)
}

/// A `tabulated n` or `tabulated nk` entry as the table (k 0 where not given).
fn tabulated(entry: &Entry) -> Result<Dispersion, String> {
    let cols = if entry.kind == "tabulated nk" { 3 } else { 2 };
    let rows = table_rows(entry, cols)?;
    if let Some(r) = rows
        .iter()
        .find(|r| r[1] <= 0.0 || r.get(2).is_some_and(|k| *k < 0.0))
    {
        return Err(format!(
            "{}: at {} um n must be positive and k not negative",
            entry.kind, r[0]
        ));
    }
    let rows = rows
        .iter()
        .map(|r| [r[0], r[1], r.get(2).copied().unwrap_or(0.0)])
        .collect();
    Ok(Dispersion::Table { rows: intern(rows) })
}

/// The part of an entry's `wavelength_range` (um; absent: all of it) inside 0.38-0.78 um,
/// where the camera's bands lie.
fn visible_part(entry: &Entry) -> Result<[f64; 2], String> {
    let (mut lo, mut hi) = (0.38f64, 0.78f64);
    if let Some(r) = entry.wavelength_range.as_deref() {
        let v = entry.numbers(r)?;
        if v.len() != 2 || v[0].partial_cmp(&v[1]) != Some(std::cmp::Ordering::Less) {
            return Err(format!(
                "wavelength_range {r:?}: expected two increasing numbers"
            ));
        }
        (lo, hi) = (lo.max(v[0]), hi.min(v[1]));
    }
    if lo.partial_cmp(&hi) != Some(std::cmp::Ordering::Less) {
        return Err("wavelength_range: does not reach the visible (0.38-0.78 um)".into());
    }
    Ok([lo, hi])
}

/// The three-term Cauchy through `rows` (`(l_um, n)`, a formula sampled) when it holds them
/// within [`FORMULA_FIT_TOLERANCE`], else the worst miss as the reason.
fn held_within(rows: &[(f64, f64)], kind: &str) -> Result<Dispersion, String> {
    if rows.iter().any(|r| !(r.1 > 0.0 && r.1.is_finite())) {
        return Err(format!(
            "{kind}: the formula gives no real index over the visible"
        ));
    }
    let d = cauchy_through(rows)?;
    let (worst, at) = rows
        .iter()
        .map(|&(l, n)| ((d.index_at(l * 1e3) - n).abs(), l))
        .fold((0.0, 0.0), |a, b| if b.0 > a.0 { b } else { a });
    if worst > FORMULA_FIT_TOLERANCE {
        return Err(format!(
            "{kind}: a three-term Cauchy misses the formula by {worst:.4} at {:.0} nm (filmscope holds it within {FORMULA_FIT_TOLERANCE})",
            at * 1e3
        ));
    }
    Ok(d)
}

/// How far the three-term Cauchy that stands for a formula filmscope cannot hold exactly
/// (`formula 4`) may miss it over the visible.
pub const FORMULA_FIT_TOLERANCE: f64 = 1e-3;

/// The least-squares Cauchy `a + b / l^2 + c / l^4` (l in um) through `(l_um, n)` rows:
/// as many terms as the rows allow (one row: a constant).
pub fn cauchy_fit(rows: &[(f64, f64)]) -> Result<Dispersion, MaterialError> {
    cauchy_through(rows).map_err(MaterialError::Entry)
}

/// [`cauchy_fit`], its problem in words.
fn cauchy_through(rows: &[(f64, f64)]) -> Result<Dispersion, String> {
    if rows.is_empty() {
        return Err("tabulated n: no rows".into());
    }
    if rows.iter().any(|r| !(r.0 > 0.0 && r.1.is_finite())) {
        return Err("tabulated n: every row needs a positive wavelength and a finite n".into());
    }
    let distinct = {
        let mut l: Vec<f64> = rows.iter().map(|r| r.0).collect();
        l.sort_by(f64::total_cmp);
        l.dedup();
        l.len()
    };
    let n_same = rows.iter().all(|r| r.1 == rows[0].1);
    if distinct == 1 || n_same {
        return Ok(Dispersion::constant(rows[0].1));
    }
    let terms = distinct.min(3);
    // Normal equations in x = 1 / l^2, scaled by the largest x for conditioning; the terms
    // the rows cannot determine are an identity block (their coefficients come out 0).
    let xmax = rows.iter().map(|r| 1.0 / (r.0 * r.0)).fold(0.0, f64::max);
    let mut h = nalgebra::Matrix3::<f64>::identity();
    h.view_mut((0, 0), (terms, terms)).fill(0.0);
    let mut g = nalgebra::Vector3::<f64>::zeros();
    for &(l, n) in rows {
        let x = 1.0 / (l * l) / xmax;
        let basis = [1.0, x, x * x];
        for i in 0..terms {
            for j in 0..terms {
                h[(i, j)] += basis[i] * basis[j];
            }
            g[i] += basis[i] * n;
        }
    }
    let coef = h
        .cholesky()
        .map(|c| c.solve(&g))
        .filter(|c| c.iter().all(|v| v.is_finite()))
        .ok_or("tabulated n: the rows do not determine a Cauchy fit")?;
    let coef = |i: usize| coef[i];
    Ok(Dispersion::Cauchy {
        a: coef(0),
        b_um2: coef(1) / xmax,
        c_um4: coef(2) / (xmax * xmax),
    })
}

/// The file names of [`index_files`], written beside `summary.json`.
pub const INDEX_FILES: [&str; 2] = ["index.csv", "index.yml"];

/// The estimated index `d` as [`INDEX_FILES`]: `index.csv` (n at every band of
/// `bands_nm`) and `index.yml` (a refractiveindex.info entry valid over the bands' span);
/// `None` when it has no finite index at 550 nm (no index found).
pub fn index_files(
    d: &Dispersion,
    bands_nm: &[f64],
    comment: &str,
) -> Option<[(&'static str, String); 2]> {
    if !d.index_at(550.0).is_finite() || bands_nm.is_empty() {
        return None;
    }
    let lo = bands_nm.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = bands_nm.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut sorted = bands_nm.to_vec();
    sorted.sort_by(f64::total_cmp);
    Some([
        (INDEX_FILES[0], to_csv(d, &sorted)),
        (INDEX_FILES[1], to_rii_yaml(d, [lo, hi], comment)),
    ])
}

/// A dispersion model as the files give it, tagged by `model`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "lowercase")]
pub enum DispersionRecord {
    /// n.
    Constant {
        /// The index.
        n: f64,
    },
    /// n = a + b / l^2 + c / l^4, l in um.
    #[serde(alias = "cauchy3")]
    Cauchy {
        /// a.
        a: f64,
        /// b, um^2.
        b_um2: f64,
        /// c, um^4 (0 when absent).
        #[serde(default)]
        c_um4: f64,
    },
    /// n^2 = a + sum b_i l^2 / (l^2 - c_i^2), l in um; up to three terms.
    Sellmeier {
        /// a.
        a: f64,
        /// The terms' strengths.
        b: Vec<f64>,
        /// The terms' resonances, um.
        c_um: Vec<f64>,
    },
    /// A measured table, rows `[wavelength_um, n, k]` in increasing wavelength.
    Table {
        /// The rows.
        rows: Vec<[f64; 3]>,
    },
}

impl From<Dispersion> for DispersionRecord {
    fn from(d: Dispersion) -> Self {
        match d {
            Dispersion::Constant { n } => Self::Constant { n },
            Dispersion::Cauchy { a, b_um2, c_um4 } => Self::Cauchy { a, b_um2, c_um4 },
            Dispersion::Sellmeier { a, b, c_um } => {
                let terms = b.iter().zip(c_um).filter(|(b, _)| **b != 0.0);
                let (b, c_um) = terms.map(|(b, c)| (*b, c)).unzip();
                Self::Sellmeier { a, b, c_um }
            }
            Dispersion::Table { rows } => Self::Table {
                rows: rows.to_vec(),
            },
        }
    }
}

impl DispersionRecord {
    /// The record of `d` when it is dispersive, `None` for a constant index (which
    /// `truth.json` and the glTF extras give as a number beside it).
    pub fn dispersive(d: &Dispersion) -> Option<Self> {
        (!d.is_constant()).then(|| Self::from(*d))
    }

    /// The model; an error names the member at fault.
    pub fn dispersion(&self) -> Result<Dispersion, MaterialError> {
        match self {
            Self::Constant { n } => Ok(Dispersion::constant(*n)),
            Self::Cauchy { a, b_um2, c_um4 } => Ok(Dispersion::Cauchy {
                a: *a,
                b_um2: *b_um2,
                c_um4: *c_um4,
            }),
            Self::Sellmeier { a, b, c_um } => sellmeier(*a, b, c_um),
            Self::Table { rows } => {
                let ok = |r: &[f64; 3]| {
                    r.iter().all(|x| x.is_finite()) && r[0] > 0.0 && r[1] > 0.0 && r[2] >= 0.0
                };
                if rows.is_empty()
                    || !rows.iter().all(ok)
                    || rows.windows(2).any(|w| w[1][0] <= w[0][0])
                {
                    return Err(MaterialError::Record("table: `rows` must be [wavelength_um, n, k] with wavelengths positive and increasing, n positive and k not negative".into()));
                }
                Ok(Dispersion::Table {
                    rows: intern(rows.clone()),
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {

    /// n(550 nm) = 2.1, but below 450 nm the index falls under the ambient's and turns
    /// negative (3.806 - 0.1561 / l^4, l in um).
    const SINKING: Dispersion = Dispersion::Cauchy {
        a: 3.806,
        b_um2: 0.0,
        c_um4: -0.1561,
    };

    #[test]
    fn an_index_is_checked_over_the_whole_band() {
        assert!((SINKING.index_at(550.0) - 2.1).abs() < 0.01);
        assert!(SINKING.index_at(430.0) < 0.0);
        let bands: Vec<f64> = (0..101).map(|i| 420.0 + 3.0 * f64::from(i)).collect();
        let e = check_over_band(&SINKING, &bands, 1.0)
            .expect_err("refused")
            .to_string();
        assert!(e.starts_with("n(420.0 nm) = -1.2"), "{e}");
        assert!(e.contains("not above the ambient's index 1.0000"), "{e}");
        // The red half of the band is fine; a denser ambient is not.
        let red: Vec<f64> = bands.iter().copied().filter(|&l| l >= 510.0).collect();
        check_over_band(&SINKING, &red, 1.0).expect("red half");
        let e = check_over_band(&Dispersion::constant(1.3), &red, 1.33)
            .expect_err("water")
            .to_string();
        assert!(e.starts_with("n(510.0 nm) = 1.3000"), "{e}");
        // A Sellmeier pole inside the band gives no finite index there.
        let pole = Dispersion::Sellmeier {
            a: 1.0,
            b: [1.0, 0.0, 0.0],
            c_um: [0.6, 0.0, 0.0],
        };
        let e = check_over_band(&pole, &bands, 1.0).expect_err("pole");
        assert!(matches!(e, MaterialError::OverBand { .. }), "{e}");
    }

    use super::*;

    /// Every model written as YAML reads back with the same n to 1e-9 over the visible.
    #[test]
    fn yaml_round_trip_for_each_form() {
        let models = [
            Dispersion::constant(1.46),
            Dispersion::Cauchy {
                a: 1.45,
                b_um2: 0.0042,
                c_um4: 0.00011,
            },
            materials::zns_debenham(),
            materials::MGF2_DODGE_O,
            materials::TA2O5_GAO,
            materials::SI_GREEN,
        ];
        for d in models {
            let yaml = to_rii_yaml(&d, [380.0, 780.0], "test");
            let back = from_rii_yaml(&yaml).unwrap_or_else(|e| panic!("{e}\n{yaml}"));
            for l in [380.0, 450.0, 550.0, 650.0, 780.0] {
                let (a, b) = (d.index_at(l), back.index_at(l));
                assert!((a - b).abs() < 1e-9, "{d:?} at {l}: {a} vs {b}\n{yaml}");
                let (a, b) = (d.extinction_at(l), back.extinction_at(l));
                assert!((a - b).abs() < 1e-12, "{d:?} at {l}: k {a} vs {b}");
            }
        }
    }

    /// A file as the database writes it (formula 2, quoted type, a comment, a clear glass's
    /// k table after), tables held as tables (exact at their rows, linear between), and a
    /// formula whose k table absorbs held as a table of both.
    #[test]
    fn reads_database_style_entries() {
        let bk7 = "REFERENCES: \"SCHOTT\"\nDATA:\n  - type: formula 2\n    wavelength_range: 0.3 2.5\n    coefficients: 0 1.03961212 0.00600069867 0.231792344 0.0200179144 1.01046945 103.560653\n  - type: tabulated k\n    data: |\n        0.3 1e-6\nSPECS:\n  n_absolute: true\n";
        let d = from_rii_yaml(bk7).expect("bk7");
        assert!(
            (d.index_at(587.6) - 1.5168).abs() < 1e-4,
            "{}",
            d.index_at(587.6)
        );
        let table = "DATA:\n  - type: tabulated n\n    data: |\n        0.4 1.470\n        0.5 1.462\n        0.6 1.458\n        0.7 1.455\n";
        let d = from_rii_yaml(table).expect("table");
        assert_eq!(d.index_at(500.0), 1.462);
        assert!((d.index_at(550.0) - 1.460).abs() < 1e-12);
        assert_eq!(d.extinction_at(550.0), 0.0);
        let nk = "DATA:\n  - type: tabulated nk\n    data: |\n        0.40 5.613 0.296\n        0.50 4.294 0.044165\n        0.60 3.940 0.019934\n";
        let d = from_rii_yaml(nk).expect("nk");
        assert_eq!(
            (d.index_at(500.0), d.extinction_at(500.0)),
            (4.294, 0.044165)
        );
        assert!((d.extinction_at(450.0) - 0.5 * (0.296 + 0.044165)).abs() < 1e-12);
        let absorbing = "DATA:\n  - type: formula 5\n    coefficients: 2.0 0.02 -2\n  - type: tabulated k\n    data: |\n        0.4 0.02\n        0.8 0.0\n";
        let d = from_rii_yaml(absorbing).expect("formula with k");
        assert!(matches!(d, Dispersion::Table { .. }), "{d:?}");
        assert!((d.index_at(500.0) - (2.0 + 0.02 / 0.25)).abs() < 1e-12);
        assert!((d.extinction_at(600.0) - 0.01).abs() < 1e-12);
        for bad in ["0.5 1.4\n        0.4 1.5", "0.5 -1.4", "0.5 x"] {
            let text = format!("DATA:\n  - type: tabulated n\n    data: |\n        {bad}\n");
            assert!(from_rii_yaml(&text).is_err(), "{bad}");
        }
        assert!(from_rii_yaml("DATA:\n  - type: formula 3\n    coefficients: 1 2 3\n").is_err());
        // Formula 4, TiO2 (rutile, ordinary; Devore 1951): n^2 = 5.913 + 0.2441 / (l^2 - 0.0803).
        let tio2 = "DATA:\n  - type: formula 4\n    wavelength_range: 0.43 1.53\n    coefficients: 5.913 0.2441 0 0.0803 1\n";
        let d = from_rii_yaml(tio2).expect("formula 4");
        for l in [450.0, 550.0, 650.0, 750.0] {
            let x = (l * 1e-3f64).powi(2);
            let want = (5.913 + 0.2441 / (x - 0.0803)).sqrt();
            assert!(
                (d.index_at(l) - want).abs() < 1e-3,
                "{l}: {} vs {want}",
                d.index_at(l)
            );
        }
        // A formula 4 with power terms (l^2 and l^-2, as the database's crystals have).
        let zns = "DATA:\n  - type: formula 4\n    wavelength_range: 0.4 1.0\n    coefficients: 5.131 0 0 0 0 0 0 0 0 0.1 -2 -0.001 2\n";
        let d = from_rii_yaml(zns).expect("power terms");
        let x = 0.55f64 * 0.55;
        let want = (5.131 + 0.1 / x - 0.001 * x).sqrt();
        assert!((d.index_at(550.0) - want).abs() < 1e-3);
        let out = from_rii_yaml(
            "DATA:\n  - type: formula 4\n    wavelength_range: 2 5\n    coefficients: 2\n",
        );
        assert!(matches!(out, Err(e) if e.to_string().contains("visible")));
        assert!(from_rii_yaml("nothing: here\n").is_err());
    }

    /// A database file with the keys filmscope leaves unread (multi-line `REFERENCES`,
    /// `SPECS`, `CONDITIONS`) reads; a file that is not YAML, or whose entry has a key of the
    /// wrong shape, is one line naming the key; a comment with a backslash or a line break
    /// is written so that it reads back.
    #[test]
    fn yaml_is_read_by_a_parser() {
        let db = "# a comment\nREFERENCES: \"Malitson 1965: <a href=\\\"x\\\">link</a>\"\nCOMMENTS: >\n  folded\n  text\nDATA:\n  - type: formula 1\n    wavelength_range: 0.21 6.7\n    coefficients: 0 0.6961663 0.0684043 0.4079426 0.1162414 0.8974794 9.896161\nCONDITIONS:\n  temperature: 293.15\nSPECS:\n  n_absolute: true\n  wavelength_vacuum: true\n  nd: 1.4585\n";
        let d = from_rii_yaml(db).expect("fused silica");
        assert!(
            (d.index_at(587.6) - 1.4585).abs() < 1e-4,
            "{}",
            d.index_at(587.6)
        );
        let e = from_rii_yaml("DATA:\n  - type: formula 1\n   coefficients: [1\n")
            .expect_err("not YAML")
            .to_string();
        assert!(
            e.starts_with("not a refractiveindex.info YAML file: "),
            "{e}"
        );
        assert_eq!(e.lines().count(), 1, "{e}");
        let e = from_rii_yaml("DATA:\n  - type: formula 1\n    coefficients: {a: 1}\n")
            .expect_err("a map for coefficients")
            .to_string();
        assert!(e.contains("DATA[0].coefficients"), "{e}");
        let e = from_rii_yaml("DATA: 3\n")
            .expect_err("DATA not a list")
            .to_string();
        assert!(e.contains("DATA"), "{e}");
        let yaml = to_rii_yaml(
            &Dispersion::constant(1.5),
            [400.0, 700.0],
            "estimate of C:\\caps\\a \"b\"\nsecond line",
        );
        assert!(
            yaml.contains("COMMENTS: \"estimate of C:\\\\caps\\\\a 'b'\\nsecond line\"\n"),
            "{yaml}"
        );
        assert_eq!(
            from_rii_yaml(&yaml).expect("reads back").index_at(550.0),
            1.5
        );
    }

    /// JSON forms: numbers, names, summary objects; bad ones name the key.
    #[test]
    fn json_forms() {
        use serde_json::json;
        let n = |v: serde_json::Value| {
            dispersion_from_json(&v)
                .map(|d| d.index_at(550.0))
                .map_err(|e| e.to_string())
        };
        assert_eq!(n(json!(1.5)), Ok(1.5));
        assert!((n(json!("sio2")).expect("sio2") - 1.459911).abs() < 1e-6);
        assert_eq!(
            n(json!({"model": "cauchy", "a": 1.4, "b_um2": 0.0})),
            Ok(1.4)
        );
        let e = n(json!({"model": "cauchy", "a": 1.4})).expect_err("no b");
        assert!(e.contains("b_um2"), "{e}");
        assert!(n(json!("unobtainium")).is_err());
        assert!(n(json!(0.5)).is_err());
    }
}
