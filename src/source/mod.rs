//! Where band frames come from: the software camera, ENVI captures replayed row by row and
//! a rig's live sweep ([`live`]), the messages they stream (`msg`) and a sweep held whole
//! ([`SweepCube`]).

mod capture;
mod cube;
pub mod live;
mod msg;
mod replay;
mod sim;

pub use capture::CaptureSource;
pub use cube::SweepCube;
pub use msg::{calibrate_block, RowBlock, Samples, StreamMsg};
pub use replay::{Frames, ReplaySource};
pub use sim::SimSource;

use std::path::PathBuf;

use crossbeam_channel::Sender;
use filmscope_core::solve::SweepSpec;

/// Why a source cannot stream a sweep: one line, naming the file or scene at fault.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// The capture's files or values (see [`crate::io::CaptureError`]).
    #[error(transparent)]
    Capture(#[from] crate::io::CaptureError),
    /// A cube that cannot be read.
    #[error(transparent)]
    Envi(#[from] crate::io::EnviError),
    /// A value outside the bounds [`crate::limits`] states.
    #[error(transparent)]
    Limit(#[from] crate::limits::LimitError),
    /// Too few bands to find fringes.
    #[error("{bands} bands: at least {MIN_BANDS} are needed to find fringes")]
    TooFewBands {
        /// Bands given.
        bands: usize,
    },
    /// More bands than the solver's fixed state holds.
    #[error(
        "{bands} bands: at most {} are supported",
        filmscope_core::solve::sweep::MAX_BANDS
    )]
    TooManyBands {
        /// Bands given.
        bands: usize,
    },
    /// Cubes without the wavelength of each band.
    #[error("{}: the cubes have no `wavelength` list; filmscope needs each band's wavelength", .0.display())]
    NoWavelengths(PathBuf),
    /// The problem of a named capture or scene.
    #[error("{name}: {problem}")]
    In {
        /// The capture's path or the scene's name.
        name: String,
        /// What is wrong with it.
        problem: Box<SourceError>,
    },
}

impl SourceError {
    /// This problem as one of the capture or scene `name`.
    pub fn of(self, name: impl std::fmt::Display) -> Self {
        Self::In {
            name: name.to_string(),
            problem: Box::new(self),
        }
    }
}

/// Callers whose own errors are still one line of text take a source's line as it is.
impl From<SourceError> for String {
    fn from(e: SourceError) -> Self {
        e.to_string()
    }
}

/// Fewest bands in which fringes can be found.
pub const MIN_BANDS: usize = 16;

/// A producer of one sweep's stream. `stream` runs on its own thread and must end the stream
/// with `SweepEnd` or `Abort`; a send error means the pipeline stopped listening.
pub trait Source: Send {
    /// The sweep's geometry and optics, known before the first row.
    fn spec(&self) -> &SweepSpec;
    /// Incidence angles in streaming order, degrees (for progress and reports).
    fn angles_deg(&self) -> Vec<f64>;
    /// Streams the sweep into `tx`.
    fn stream(&mut self, tx: &Sender<StreamMsg>);
    /// Streams the sweep into `tx` as [`Source::stream`] does, but only the image rows in
    /// `rows` (sorted) need be sent: for a consumer that reads a few pixels' spectra. A
    /// source that cannot skip rows streams them all (the consumer ignores the rest).
    fn stream_rows(&mut self, tx: &Sender<StreamMsg>, rows: &[usize]) {
        let _ = rows;
        self.stream(tx);
    }
    /// Whether [`Source::stream`] may be called again for the same data (a capture on disk,
    /// the software camera; not a live camera).
    fn replayable(&self) -> bool {
        true
    }
    /// The order the stream's rows come in: the workers hold them accordingly.
    fn row_order(&self) -> RowOrder {
        RowOrder::BandMajor
    }
    /// What the caller should know about the data streamed so far, one line each (a
    /// reference clipped at full scale, say): read after the sweep, added to the result's
    /// notes.
    fn notes(&self) -> Vec<String> {
        Vec::new()
    }
}

/// The order of a stream's blocks of rows within an angle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RowOrder {
    /// Band by band, each band's rows top to bottom (a camera's frames, BSQ).
    BandMajor,
    /// Line by line, each run of lines with all its bands (a line-scan camera, BIL, BIP).
    LineMajor,
}

/// Builds a [`SweepSpec`] from band lists and the sample's optics.
#[allow(clippy::too_many_arguments)]
pub fn sweep_spec(
    width: usize,
    height: usize,
    bands_nm: &[f64],
    fwhm_nm: Option<&[f64]>,
    ambient_index: f64,
    substrate_index: f64,
    polarization: filmscope_core::optics::Polarization,
    index_range: [f64; 2],
    thickness_range_nm: Option<[f64; 2]>,
) -> Result<SweepSpec, SourceError> {
    // Every source passes here: bounded ranges keep the search finite in time and memory.
    crate::limits::check_index_range("search.index_range", index_range)?;
    crate::limits::check_bands("wavelength", bands_nm, "fwhm", fwhm_nm)?;
    if bands_nm.len() < MIN_BANDS {
        return Err(SourceError::TooFewBands {
            bands: bands_nm.len(),
        });
    }
    let bands: heapless::Vec<f64, { filmscope_core::solve::sweep::MAX_BANDS }> =
        heapless::Vec::from_slice(bands_nm).map_err(|()| SourceError::TooManyBands {
            bands: bands_nm.len(),
        })?;
    let mut fwhm = heapless::Vec::new();
    for i in 0..bands.len() {
        let w = match fwhm_nm {
            Some(f) => f[i],
            // No fwhm: a passband as narrow as the band spacing (capture-format.md).
            None => {
                let j = if i + 1 < bands.len() { i + 1 } else { i - 1 };
                (bands[j] - bands[i]).abs()
            }
        };
        let _ = fwhm.push(w);
    }
    let thickness_range_nm = thickness_range_nm.unwrap_or_else(|| {
        [
            DEFAULT_THICKNESS_RANGE_NM[0],
            resolvable_thickness_nm(&bands, &fwhm),
        ]
    });
    crate::limits::check_thickness_range("search.thickness_range_nm", thickness_range_nm)?;
    Ok(SweepSpec {
        back_face: filmscope_core::optics::BackFace::None,
        width,
        height,
        bands_nm: bands,
        fwhm_nm: fwhm,
        ambient_index,
        substrate_index,
        substrate: filmscope_core::optics::Dispersion::constant(substrate_index),
        polarization,
        index_range,
        thickness_range_nm,
        model_error: filmscope_core::solve::sample::DEFAULT_MODEL_ERROR,
        rig_tolerance: 1.0,
        options: Default::default(),
    })
}

/// Default search ranges when a capture gives none.
pub const DEFAULT_INDEX_RANGE: [f64; 2] = [1.2, 3.0];
/// Default thickness search range, nm: from its low end up to the thickest film the bands
/// resolve ([`resolvable_thickness_nm`]), never below its high end.
pub const DEFAULT_THICKNESS_RANGE_NM: [f64; 2] = [20.0, 2000.0];

/// The index of the thickest films the default search range reaches: a low-index film
/// (polymer, silica, MgF2) is the thickest for a given fringe period.
const RESOLVED_FILM_INDEX: f64 = 1.45;

/// The thickest film whose fringes the bands resolve, nm: a fringe period of at least three
/// band steps and twice the passband's FWHM (which leaves it about 40 % of its contrast) at
/// normal incidence for a film of index [`RESOLVED_FILM_INDEX`], over the band's red half
/// (where the search looks for thick films; the median of its bands). The period of a
/// film `d` thick at wavelength `l` is `l^2 / (2 n d)`. Rounded down to 100 nm, at least
/// the high end of [`DEFAULT_THICKNESS_RANGE_NM`], at most [`crate::limits::MAX_THICKNESS_NM`].
pub fn resolvable_thickness_nm(bands_nm: &[f64], fwhm_nm: &[f64]) -> f64 {
    let nb = bands_nm.len().min(fwhm_nm.len());
    let mut d: Vec<f64> = (nb / 2..nb)
        .filter_map(|i| {
            let j = if i + 1 < nb { i + 1 } else { i.checked_sub(1)? };
            let step = (bands_nm[j] - bands_nm[i]).abs();
            let period = (3.0 * step).max(2.0 * fwhm_nm[i]);
            let l = bands_nm[i];
            (period > 0.0).then(|| l * l / (2.0 * RESOLVED_FILM_INDEX * period))
        })
        .filter(|d| d.is_finite())
        .collect();
    if d.is_empty() {
        return DEFAULT_THICKNESS_RANGE_NM[1];
    }
    d.sort_by(f64::total_cmp);
    let median = d[d.len() / 2];
    ((median / 100.0).floor() * 100.0).clamp(
        DEFAULT_THICKNESS_RANGE_NM[1],
        crate::limits::MAX_THICKNESS_NM,
    )
}

/// Runs of consecutive image rows `(first, rows)` of a `height`-row frame, each at most
/// `per_run` long: every row, or only those in `only` (sorted).
pub fn row_runs(height: usize, only: Option<&[usize]>, per_run: usize) -> Vec<(usize, usize)> {
    let per_run = per_run.max(1);
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut push = |r: usize| match runs.last_mut() {
        Some((first, n)) if *first + *n == r && *n < per_run => *n += 1,
        _ => runs.push((r, 1)),
    };
    match only {
        None => (0..height).for_each(&mut push),
        Some(rows) => {
            let mut last = None;
            for &r in rows.iter().filter(|&&r| r < height) {
                if last.is_none_or(|l| r > l) {
                    push(r);
                    last = Some(r);
                }
            }
        }
    }
    runs
}

/// [`stream_band_sequential`] over the row runs `runs` only (from [`row_runs`]).
pub fn stream_runs(
    tx: &Sender<StreamMsg>,
    angles_deg: &[f64],
    bands: usize,
    runs: &[(usize, usize)],
    mut block: impl FnMut(usize, usize, usize, usize) -> Samples,
) {
    for (a, &deg) in angles_deg.iter().enumerate() {
        if tx.send(StreamMsg::Angle { incidence_deg: deg }).is_err() {
            return;
        }
        for b in 0..bands {
            for &(r0, rows) in runs {
                let msg = StreamMsg::Rows(RowBlock {
                    band: b as u16,
                    first_row: r0 as u32,
                    rows: rows as u32,
                    samples: block(a, b, r0, rows),
                });
                if tx.send(msg).is_err() {
                    return;
                }
            }
            if tx.send(StreamMsg::BandEnd { band: b as u16 }).is_err() {
                return;
            }
        }
        if tx.send(StreamMsg::AngleEnd).is_err() {
            return;
        }
    }
    let _ = tx.send(StreamMsg::SweepEnd);
}

/// Streams a band-sequential sweep into `tx`: per angle, every band's `height` rows in blocks
/// of `rows_per_block`, the samples of a block made by `block(angle, band, first_row, rows)`,
/// then the band's and the angle's end, and the sweep's end. Stops quietly when the receiver
/// is gone.
pub fn stream_band_sequential(
    tx: &Sender<StreamMsg>,
    angles_deg: &[f64],
    bands: usize,
    height: usize,
    rows_per_block: usize,
    block: impl FnMut(usize, usize, usize, usize) -> Samples,
) {
    let runs = row_runs(height, None, rows_per_block);
    stream_runs(tx, angles_deg, bands, &runs, block);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bands(lo: f64, hi: f64, step: f64) -> Vec<f64> {
        (0..)
            .map(|i| lo + step * f64::from(i))
            .take_while(|&l| l <= hi + 1e-9)
            .collect()
    }

    /// The default range reaches the thickest film whose fringes the bands resolve (a
    /// period of three steps and twice the FWHM at n = 1.45 over the red half), never less
    /// than 2000 nm.
    #[test]
    fn the_default_thickness_range_follows_the_bands() {
        let cases = [
            ((380.0, 760.0, 1.0), 2.0, 38_100.0),
            ((420.0, 720.0, 2.0), 4.0, 17_900.0),
            ((400.0, 720.0, 4.0), 10.0, 7_000.0),
            ((420.0, 720.0, 20.0), 40.0, 2_000.0),
        ];
        for ((lo, hi, step), fwhm, want) in cases {
            let b = bands(lo, hi, step);
            let f = vec![fwhm; b.len()];
            assert_eq!(
                resolvable_thickness_nm(&b, &f),
                want,
                "{lo}-{hi}/{step}, {fwhm}"
            );
        }
        let spec = sweep_spec(
            4,
            4,
            &bands(420.0, 720.0, 2.0),
            Some(&[4.0; 151]),
            1.0,
            1.52,
            filmscope_core::optics::Polarization::S,
            DEFAULT_INDEX_RANGE,
            None,
        )
        .expect("spec");
        assert_eq!(spec.thickness_range_nm, [20.0, 17_900.0]);
    }
}
