//! `summary.json`'s `index_model_choice`: how the film's index model was chosen, and the
//! evidence behind it, for people. Its shape differs by how the index came:
//!
//! - [`FittedChoice`]: fitted on the full spectra of a pixel sample (the streaming
//!   estimator, narrow field model);
//! - [`GivenChoice`]: given (`--film-index`) and held, with the sample's evidence under it;
//! - [`AbsorbingChoice`]: given as an absorbing film's n and k;
//! - [`WideChoice`]: the wide field model's strips' indices combined;
//!
//! and null for the baselines (`paper`, `brute`). Written with the keys of every object in
//! alphabetical order (`Summary` serialises it through [`crate::record::sorted`]), whatever
//! order these types declare them in. A value that is not finite is written null (its
//! member an `Option`, none).

use serde::{Deserialize, Serialize};

/// How the index model was chosen: one of the shapes above, told apart on reading by the
/// members each requires (`absorbing`, `largest_difference_from_given` with `given`,
/// `combination`, `index_source`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum IndexModelChoice {
    /// An absorbing film's n and k, given.
    Absorbing(AbsorbingChoice),
    /// The index given and held.
    Given(GivenChoice),
    /// The wide field model's strips' indices combined.
    Wide(WideChoice),
    /// The index fitted on a pixel sample's full spectra.
    Fitted(Box<FittedChoice>),
}

impl IndexModelChoice {
    /// The nuisance terms the sample fit took, when the index was fitted on one (not the
    /// wide model's, whose strips each have their own).
    pub fn nuisance_terms(&self) -> Option<&NuisanceTerms> {
        match self {
            Self::Fitted(f) => Some(&f.nuisance_terms),
            _ => None,
        }
    }

    /// The passes over the data, when the shape records them.
    pub fn passes(&self) -> Option<usize> {
        match self {
            Self::Fitted(f) => Some(f.passes),
            Self::Given(g) => Some(g.passes),
            _ => None,
        }
    }

    /// The pixels the thickness search was run on, when it was.
    pub fn pixels_searched(&self) -> Option<usize> {
        match self {
            Self::Fitted(f) => f.pixels_searched.flatten(),
            Self::Given(g) => g.sample.as_ref()?.pixels_searched.flatten(),
            _ => None,
        }
    }
}

/// The index fitted on the full spectra of a pixel sample
/// ([`crate::estimate::index_fit`]), and the per-pixel passes' checks under it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FittedChoice {
    /// Where the index came from, in words.
    pub index_source: String,
    /// The model chosen (the best candidate even when the fit failed); null when none.
    pub chosen: Option<String>,
    /// Why the fit gave no index; null when it did.
    pub failure: Option<String>,
    /// The chosen model's reduced chi-square.
    pub chi2_nu: Option<f64>,
    /// The chosen model's standard error of the index at 550 nm.
    pub n_550_sigma: Option<f64>,
    /// The pixels' noise, reflectance.
    pub noise_sigma: Option<f64>,
    /// The model error the fit took beyond the noise, reflectance.
    pub model_error: Option<f64>,
    /// The nuisance terms the fit took.
    pub nuisance_terms: NuisanceTerms,
    /// What the chosen fit leaves on the sampled sites.
    pub residual: ResidualRecord,
    /// The sites set aside as outliers, `[column, row]`.
    pub sites_set_aside: Vec<[usize; 2]>,
    /// Sites sampled.
    pub sampled_sites: usize,
    /// Sites the fit used.
    pub sites_used: usize,
    /// Pixels in each site's run.
    pub site_run_pixels: usize,
    /// Bytes the held spectra take.
    pub sample_bytes: usize,
    /// Whether the sites' thicknesses were searched.
    pub searched: bool,
    /// Starts of the fit.
    pub starts: usize,
    /// Passes over the data.
    pub passes: usize,
    /// Every model fitted.
    pub candidates: Vec<Candidate>,
    /// The rule the choice follows, in words.
    pub criterion: String,
    /// The model error the fit tolerates, reflectance.
    pub model_error_tolerated: Option<f64>,
    /// The rig's nuisance terms in the index sigma.
    pub rig_tolerance: RigTolerance,
    /// The models the fit chooses among.
    pub models: Vec<String>,
    /// Wall seconds of the fit; null when it was not timed.
    pub fit_seconds: Option<f64>,
    /// Pixels the thickness search ran on (null: none); absent from a one-pass run.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "super::present"
    )]
    pub pixels_searched: Option<Option<usize>>,
    /// Pixels the search solved (null: none searched); absent from a one-pass run.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "super::present"
    )]
    pub pixels_solved_by_search: Option<Option<usize>>,
    /// Share of the sampled sites whose per-pixel thickness disagrees with the sample's.
    pub sites_disagreeing: f64,
    /// Why every pixel was flagged, when the per-pixel pass disagreed with the sample.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_pixel_failure: Option<String>,
}

/// One model the sample fit tried.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    /// The model's name.
    pub model: String,
    /// Its parameters.
    pub parameters: usize,
    /// Chi-square in units of the noise.
    pub chi2: Option<f64>,
    /// Reduced chi-square.
    pub chi2_nu: Option<f64>,
    /// `chi2 + penalty x parameters`.
    pub score: Option<f64>,
    /// Its index at 550 nm.
    pub n_550: Option<f64>,
    /// Its standard error.
    pub n_550_sigma: Option<f64>,
    /// Whether the model is physical over the band.
    pub physical: bool,
}

/// The nuisance terms the sample fit took, each null when not taken.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NuisanceTerms {
    /// The film's extinction coefficient at 450 nm.
    pub film_k_450nm: Option<TermRecord>,
    /// The absorption's tail length, nm.
    pub absorption_tail_nm: f64,
    /// The polariser's leak.
    pub polariser_leak: Option<TermRecord>,
    /// The stage's angle offset, degrees.
    pub stage_offset_deg: Option<TermRecord>,
    /// The wavelength shift, nm.
    pub wavelength_shift_nm: Option<TermRecord>,
    /// The flare.
    pub flare: Option<TermRecord>,
    /// The side lobes.
    pub side_lobes: Option<TermRecord>,
    /// The side lobes' width, in FWHMs.
    pub side_lobe_width_fwhm: f64,
    /// Each angle's reflectance scale and offset.
    pub reflectance_terms: Vec<ReflectanceTerm>,
}

/// A nuisance term's value and its 1-sigma (null when not measured).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TermRecord {
    /// The value.
    pub value: Option<f64>,
    /// Its 1-sigma.
    pub sigma: Option<f64>,
}

/// One angle's reflectance scale and offset.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReflectanceTerm {
    /// The scale.
    pub scale: Option<f64>,
    /// The offset.
    pub offset: Option<f64>,
}

/// What the chosen fit leaves on the sampled sites, reflectance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResidualRecord {
    /// RMS of the residual.
    pub rms: Option<f64>,
    /// The noise's RMS.
    pub noise_rms: Option<f64>,
    /// The misfit beyond the noise.
    pub model_rms: Option<f64>,
    /// Correlation of neighbouring bands' residuals.
    pub band_correlation: Option<f64>,
    /// Correlation of different sites' residuals.
    pub site_correlation: Option<f64>,
    /// RMS over the band's blue third.
    pub blue_rms: Option<f64>,
    /// RMS over the band's red third.
    pub red_rms: Option<f64>,
    /// Each angle's.
    pub per_angle: Vec<AngleResidualRecord>,
    /// A one-line reading.
    pub shape: String,
}

/// One angle's residual, reflectance.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AngleResidualRecord {
    /// RMS.
    pub rms: Option<f64>,
    /// Mean.
    pub mean: Option<f64>,
    /// The noise's RMS.
    pub noise_rms: Option<f64>,
}

/// The rig's tolerance the index sigma carries.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RigTolerance {
    /// Its multiple of the one-sigma tolerance.
    pub multiple: Option<f64>,
    /// The one-sigma tolerance of each term.
    pub one_sigma: OneSigma,
}

/// The one-sigma tolerance of each nuisance term.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct OneSigma {
    /// Each angle's reflectance scale.
    pub reflectance_scale: f64,
    /// Each angle's reflectance offset.
    pub reflectance_offset: f64,
    /// The film's k at 450 nm.
    pub film_k_450nm: f64,
    /// The polariser's leak.
    pub polariser_leak: f64,
    /// The stage's offset, degrees.
    pub stage_offset_deg: f64,
    /// The wavelength shift, nm.
    pub wavelength_shift_nm: f64,
    /// The flare.
    pub flare: f64,
    /// The side lobes.
    pub side_lobes: f64,
}

/// The film's index given (`--film-index`) and held, not fitted.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GivenChoice {
    /// The material, file or number given.
    pub given: String,
    /// Why nothing was chosen, in words.
    pub reason: String,
    /// Largest difference over the bands between the held model and the given index.
    pub largest_difference_from_given: Option<f64>,
    /// Passes over the data.
    pub passes: usize,
    /// The sample's evidence under the given index, when a sample was seated.
    #[serde(default, flatten, skip_serializing_if = "Option::is_none")]
    pub sample: Option<HeldEvidence>,
}

/// The pixel sample's evidence under a given index: how well it fits, and the per-pixel
/// passes' checks (the members of [`FittedChoice`] of the same names).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeldEvidence {
    /// Reduced chi-square of the sample under the index.
    pub chi2_nu: Option<f64>,
    /// The pixels' noise, reflectance.
    pub noise_sigma: Option<f64>,
    /// Sites sampled.
    pub sampled_sites: usize,
    /// Sites used.
    pub sites_used: usize,
    /// Wall seconds of seating the sample.
    pub fit_seconds: Option<f64>,
    /// Why the index does not fit; null when it does.
    pub failure: Option<String>,
    /// Share of the sampled sites whose per-pixel thickness disagrees with the sample's.
    pub sites_disagreeing: f64,
    /// Why every pixel was flagged, when the per-pixel pass disagreed with the sample.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per_pixel_failure: Option<String>,
    /// Pixels the thickness search ran on (null: none).
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "super::present"
    )]
    pub pixels_searched: Option<Option<usize>>,
    /// Pixels the search solved.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "super::present"
    )]
    pub pixels_solved_by_search: Option<Option<usize>>,
}

impl HeldEvidence {
    /// The members of `fit` of the same names.
    pub fn of(fit: &FittedChoice) -> Self {
        Self {
            chi2_nu: fit.chi2_nu,
            noise_sigma: fit.noise_sigma,
            sampled_sites: fit.sampled_sites,
            sites_used: fit.sites_used,
            fit_seconds: fit.fit_seconds,
            failure: fit.failure.clone(),
            sites_disagreeing: fit.sites_disagreeing,
            per_pixel_failure: fit.per_pixel_failure.clone(),
            pixels_searched: fit.pixels_searched,
            pixels_solved_by_search: fit.pixels_solved_by_search,
        }
    }
}

/// An absorbing film's n and k given: each pixel's thickness fitted on the whole sweep.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AbsorbingChoice {
    /// The material given.
    pub given: String,
    /// Why nothing was chosen, in words.
    pub reason: String,
    /// Always true: the film absorbs.
    pub absorbing: bool,
    /// Its k at 550 nm.
    pub k_550nm: Option<f64>,
    /// The thickness grid's step, nm.
    pub grid_step_nm: Option<f64>,
    /// The typical pixel's residual RMS, reflectance.
    pub typical_rms: Option<f64>,
    /// The pixels' noise, reflectance.
    pub noise_sigma: Option<f64>,
}

/// The wide field model's index: the strips' indices combined.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WideChoice {
    /// The model of the combination; null when no strip gave an index.
    pub chosen: Option<String>,
    /// How the strips' indices are combined, in words.
    pub combination: String,
    /// Each strip's own index fit.
    pub strips: Vec<FittedChoice>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fitted() -> FittedChoice {
        FittedChoice {
            index_source: "full spectra of a pixel sample".into(),
            chosen: Some("cauchy".into()),
            failure: None,
            chi2_nu: Some(1.02),
            n_550_sigma: Some(1.5e-4),
            noise_sigma: None,
            model_error: Some(0.0),
            nuisance_terms: NuisanceTerms {
                film_k_450nm: Some(TermRecord {
                    value: Some(0.003),
                    sigma: None,
                }),
                absorption_tail_nm: 90.0,
                reflectance_terms: vec![ReflectanceTerm {
                    scale: Some(1.01),
                    offset: Some(-2e-4),
                }],
                ..NuisanceTerms::default()
            },
            residual: ResidualRecord {
                rms: Some(1e-3),
                noise_rms: Some(1e-3),
                model_rms: Some(0.0),
                band_correlation: None,
                site_correlation: Some(0.1),
                blue_rms: Some(1e-3),
                red_rms: Some(1e-3),
                per_angle: vec![AngleResidualRecord {
                    rms: Some(1e-3),
                    mean: Some(0.0),
                    noise_rms: None,
                }],
                shape: "within the noise".into(),
            },
            sites_set_aside: vec![[3, 4]],
            sampled_sites: 64,
            sites_used: 63,
            site_run_pixels: 5,
            sample_bytes: 1024,
            searched: true,
            starts: 2,
            passes: 2,
            candidates: vec![Candidate {
                model: "cauchy".into(),
                parameters: 2,
                chi2: Some(10.0),
                chi2_nu: Some(1.02),
                score: Some(60.0),
                n_550: Some(1.46),
                n_550_sigma: None,
                physical: true,
            }],
            criterion: "lowest chi2".into(),
            model_error_tolerated: Some(3e-4),
            rig_tolerance: RigTolerance {
                multiple: Some(1.0),
                one_sigma: OneSigma {
                    reflectance_scale: 0.01,
                    reflectance_offset: 1e-3,
                    film_k_450nm: 0.004,
                    polariser_leak: 0.01,
                    stage_offset_deg: 0.25,
                    wavelength_shift_nm: 0.3,
                    flare: 0.002,
                    side_lobes: 0.02,
                },
            },
            models: vec!["constant".into(), "cauchy".into()],
            fit_seconds: Some(0.5),
            pixels_searched: None,
            pixels_solved_by_search: None,
            sites_disagreeing: 0.0,
            per_pixel_failure: None,
        }
    }

    fn round_trip(choice: Option<IndexModelChoice>) {
        let text = crate::record::to_json(&choice).expect("serialises");
        let back: Option<IndexModelChoice> = serde_json::from_str(&text).expect("parses");
        assert_eq!(back, choice, "{text}");
    }

    /// Every shape reads back as itself, its absent and null members as written.
    #[test]
    fn every_shape_round_trips() {
        let mut one_pass = fitted();
        one_pass.per_pixel_failure = Some("every pixel flagged".into());
        let mut searched = fitted();
        searched.pixels_searched = Some(None);
        searched.pixels_solved_by_search = Some(Some(0));
        round_trip(None);
        round_trip(Some(IndexModelChoice::Fitted(Box::new(one_pass))));
        round_trip(Some(IndexModelChoice::Fitted(Box::new(searched.clone()))));
        round_trip(Some(IndexModelChoice::Given(GivenChoice {
            given: "MgF2".into(),
            reason: "given".into(),
            largest_difference_from_given: Some(0.0),
            passes: 1,
            sample: None,
        })));
        round_trip(Some(IndexModelChoice::Given(GivenChoice {
            given: "1.38".into(),
            reason: "given".into(),
            largest_difference_from_given: Some(0.0),
            passes: 3,
            sample: Some(HeldEvidence::of(&searched)),
        })));
        round_trip(Some(IndexModelChoice::Absorbing(AbsorbingChoice {
            given: "Ti".into(),
            reason: "absorbing".into(),
            absorbing: true,
            k_550nm: Some(3.0),
            grid_step_nm: Some(0.5),
            typical_rms: None,
            noise_sigma: Some(1e-3),
        })));
        round_trip(Some(IndexModelChoice::Wide(WideChoice {
            chosen: None,
            combination: "inverse-variance mean".into(),
            strips: vec![fitted(), searched],
        })));
    }

    /// The keys are written in alphabetical order, absent members left out.
    #[test]
    fn keys_are_sorted_and_absent_members_left_out() {
        let text = crate::record::to_json(&IndexModelChoice::Fitted(Box::new(fitted())))
            .expect("serialises");
        assert!(
            text.starts_with(r#"{"candidates":[{"chi2":10.0,"#),
            "{text}"
        );
        assert!(!text.contains("pixels_searched"), "{text}");
        assert!(!text.contains("per_pixel_failure"), "{text}");
        assert!(text.contains(r#""side_lobes":null"#), "{text}");
    }
}
