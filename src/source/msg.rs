//! The messages that flow between the pipeline's stages.
//!
//! A sweep is `Angle`, rows, `AngleEnd`, ... , `SweepEnd`; the end of a stream is always said
//! explicitly (`SweepEnd` or `Abort`), never inferred from a closed channel.

use filmscope_core::calibrate::calibrate_row;

/// Samples of a block of rows of one band.
#[derive(Clone, Debug, PartialEq)]
pub enum Samples {
    /// Calibrated reflectance (`+inf` saturated, NaN no usable reference).
    Reflectance(Vec<f32>),
    /// Raw counts with their references (same length), to be calibrated.
    Raw {
        /// The sample's counts.
        counts: Vec<f32>,
        /// Dark counts (absent: zero).
        dark: Option<Vec<f32>>,
        /// White reference counts.
        white: Vec<f32>,
        /// Reflectance of the white reference.
        white_reflectance: f32,
        /// ADC full scale (`f32::INFINITY` if unknown).
        saturation_counts: f32,
    },
}

/// `rows` consecutive rows of band `band`, starting at `first_row`.
#[derive(Clone, Debug, PartialEq)]
pub struct RowBlock {
    /// Band index (into the sweep's band list).
    pub band: u16,
    /// First image row.
    pub first_row: u32,
    /// Number of rows.
    pub rows: u32,
    /// `rows * width` samples, row-major.
    pub samples: Samples,
}

/// One message of a sweep stream.
#[derive(Clone, Debug, PartialEq)]
pub enum StreamMsg {
    /// An angle starts; every row until `AngleEnd` belongs to it.
    Angle {
        /// Measured incidence angle, degrees.
        incidence_deg: f64,
    },
    /// Rows of one band.
    Rows(RowBlock),
    /// Every row of band `band` of the current angle has been sent (band-sequential sources
    /// only: a line-interleaved source completes all bands together at `AngleEnd`).
    BandEnd {
        /// The band.
        band: u16,
    },
    /// The current angle is complete.
    AngleEnd,
    /// The sweep is complete.
    SweepEnd,
    /// The source failed; the reason in one line.
    Abort(String),
}

/// Calibrated reflectance of a block of `rows` rows (raw counts calibrated, reflectance
/// passed through).
pub fn calibrate_block(samples: Samples, rows: usize, width: usize) -> Vec<f32> {
    match samples {
        Samples::Reflectance(v) => v,
        Samples::Raw {
            counts,
            dark,
            white,
            white_reflectance,
            saturation_counts,
        } => {
            let mut out = vec![f32::NAN; counts.len()];
            if counts.len() != rows * width
                || white.len() != counts.len()
                || dark.as_ref().is_some_and(|d| d.len() != counts.len())
            {
                return out;
            }
            for k in 0..rows {
                let s = k * width..(k + 1) * width;
                calibrate_row(
                    &counts[s.clone()],
                    dark.as_ref().map(|d| &d[s.clone()]),
                    &white[s.clone()],
                    white_reflectance,
                    saturation_counts,
                    &mut out[s],
                );
            }
            out
        }
    }
}
