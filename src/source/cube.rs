//! A sweep held whole in memory.
//!
//! The streaming estimator never needs [`SweepCube`]: it exists for the whole-cube baselines
//! (`paper`, `brute`), for evaluation and for the equivalence tests.

use filmscope_core::optics::Polarization;

/// Calibrated reflectance of every angle, band and pixel of one sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepCube {
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Band centres, nm.
    pub bands_nm: Vec<f64>,
    /// Band FWHM, nm (one per band).
    pub fwhm_nm: Vec<f64>,
    /// Incidence angle of each cube, degrees (any order).
    pub angles_deg: Vec<f64>,
    /// Ambient index.
    pub ambient_index: f64,
    /// Substrate index.
    pub substrate_index: f64,
    /// Polarisation of the measured light.
    pub polarization: Polarization,
    /// The substrate's back face.
    pub back_face: filmscope_core::optics::BackFace,
    /// Film index search range.
    pub index_range: [f64; 2],
    /// Thickness search range, nm.
    pub thickness_range_nm: [f64; 2],
    /// Reflectance per angle, BSQ: `data[angle][(band * height + row) * width + col]`; `+inf`
    /// marks a saturated sample, NaN one without a usable reference.
    pub data: Vec<Vec<f32>>,
}

impl SweepCube {
    /// Samples held: pixels x bands x angles.
    pub fn samples(&self) -> u64 {
        (self.width * self.height * self.bands_nm.len() * self.angles_deg.len()) as u64
    }

    /// The spectrum of pixel `(col, row)` at angle `angle`, into `out` (one value per band).
    pub fn spectrum_into(&self, angle: usize, col: usize, row: usize, out: &mut [f32]) {
        let plane = self.width * self.height;
        let cube = &self.data[angle];
        for (b, o) in out.iter_mut().enumerate() {
            *o = cube[b * plane + row * self.width + col];
        }
    }
}
