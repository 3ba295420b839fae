//! A production line's worth of samples: one base scene, presented sample after sample with
//! the variations a line shows, deterministic from a seed.
//!
//! Sample `k` (0-based) is the base scene with
//! - a slow drift: the whole film `drift_nm_per_sample * k` nm thicker;
//! - sample-to-sample scatter: a normal offset of `scatter_nm` (1 sigma) on the thickness and
//!   `index_scatter` on the index, and a fresh noise seed;
//! - every `defect_every`-th sample (from the second on: `k % defect_every == 1`) a local
//!   defect: a square patch a quarter of the sensor wide, `defect_nm` thicker;
//! - every `defect_every`-th sample from the fifth on (`k % defect_every == 4`) a whole film
//!   `shift_fraction` too thick.
//!
//! So with the defaults, among the first three samples, the second fails and the others pass.

use filmscope_core::optics::Dispersion;

use crate::rng::Rng;
use crate::Scene;

/// What was done to a sample (for logs and tests).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleKind {
    /// The base film with drift and scatter.
    Nominal,
    /// A local patch too thick.
    Defect,
    /// The whole film too thick.
    Shifted,
}

impl SampleKind {
    /// `nominal`, `defect` or `shifted`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Nominal => "nominal",
            Self::Defect => "defect",
            Self::Shifted => "shifted",
        }
    }
}

/// The generator of a line's samples.
#[derive(Clone, Debug)]
pub struct SampleSequence {
    /// The scene every sample starts from.
    pub base: Scene,
    /// Seed of the scatter and of each sample's noise.
    pub seed: u64,
    /// Thickness drift per sample, nm.
    pub drift_nm_per_sample: f64,
    /// Thickness scatter between samples (1 sigma), nm.
    pub scatter_nm: f64,
    /// Index scatter between samples (1 sigma).
    pub index_scatter: f64,
    /// Period of the out-of-tolerance samples (0: none).
    pub defect_every: u64,
    /// How much thicker a defect patch is, nm.
    pub defect_nm: f64,
    /// How much too thick a shifted film is, as a fraction.
    pub shift_fraction: f64,
}

impl SampleSequence {
    /// The defaults: 0.3 nm drift a sample, 1.5 nm and 0.002 scatter, a defect of +150 nm and
    /// a 15 % shift, each every 7 samples.
    pub fn new(base: Scene, seed: u64) -> Self {
        Self {
            base,
            seed,
            drift_nm_per_sample: 0.3,
            scatter_nm: 1.5,
            index_scatter: 0.002,
            defect_every: 7,
            defect_nm: 150.0,
            shift_fraction: 0.15,
        }
    }

    /// What sample `k` is.
    pub fn kind(&self, k: u64) -> SampleKind {
        match (self.defect_every, k) {
            (0, _) => SampleKind::Nominal,
            (p, k) if k % p == 1 => SampleKind::Defect,
            (p, k) if p > 4 && k % p == 4 => SampleKind::Shifted,
            _ => SampleKind::Nominal,
        }
    }

    /// The reference sample: the base scene itself, without drift, scatter or defect (its
    /// truth is the scene file's).
    pub fn reference(&self) -> Scene {
        let mut s = self.base.clone();
        s.name = format!("{}-reference", self.base.name);
        s
    }

    /// Sample `k`'s scene.
    pub fn scene(&self, k: u64) -> (Scene, SampleKind) {
        let mut rng = Rng::from_words(&[self.seed, k, 0x11e5]);
        let mut s = self.base.clone();
        s.seed = self.base.seed.wrapping_add(k.wrapping_mul(0x9e37_79b9)) ^ self.seed;
        s.name = format!("{}-{k}", self.base.name);
        let offset = self.drift_nm_per_sample * k as f64 + self.scatter_nm * rng.normal();
        let kind = self.kind(k);
        let (w, h) = (s.sensor.width, s.sensor.height);
        let side = (w / 4).max(1);
        let (x0, y0) = (
            (w / 2).saturating_sub(side / 2),
            (h / 2).saturating_sub(side / 2),
        );
        for (i, t) in s.thickness_nm.iter_mut().enumerate() {
            let (x, y) = (i % w, i / w);
            let mut v = f64::from(*t) + offset;
            match kind {
                SampleKind::Defect
                    if (x0..x0 + side).contains(&x) && (y0..y0 + side).contains(&y) =>
                {
                    v += self.defect_nm;
                }
                SampleKind::Shifted => v *= 1.0 + self.shift_fraction,
                _ => {}
            }
            *t = v.max(1.0) as f32;
        }
        if let Dispersion::Constant { n } = s.stack.film {
            s.stack.film = Dispersion::constant(n + self.index_scatter * rng.normal());
        }
        (s, kind)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn base() -> Scene {
        Scene::from_toml(
            include_str!("../../config/scenes/rig-tiny.toml"),
            "rig-tiny",
        )
        .expect("scene")
    }

    #[test]
    fn the_line_is_deterministic_with_defects_and_drift() {
        let seq = SampleSequence::new(base(), 3);
        let kinds: Vec<SampleKind> = (0..8).map(|k| seq.kind(k)).collect();
        use SampleKind::*;
        assert_eq!(
            kinds,
            vec![Nominal, Defect, Nominal, Nominal, Shifted, Nominal, Nominal, Nominal]
        );
        let (a, _) = seq.scene(2);
        let (b, _) = seq.scene(2);
        assert_eq!(a.thickness_nm, b.thickness_nm);
        assert_eq!(a.seed, b.seed);
        let mean = |s: &Scene| {
            s.thickness_nm.iter().map(|&t| f64::from(t)).sum::<f64>() / s.thickness_nm.len() as f64
        };
        let (d, _) = seq.scene(1);
        let (w, h) = (d.sensor.width, d.sensor.height);
        let centre = d.thickness_nm[h / 2 * w + w / 2] - seq.base.thickness_nm[h / 2 * w + w / 2];
        assert!(centre > 140.0, "patch {centre}");
        let (sh, _) = seq.scene(4);
        assert!(mean(&sh) > 1.12 * mean(&seq.base));
        // Drift: 0.3 nm a sample, scatter 1.5 nm: 100 samples on, 30 nm thicker give or take.
        let (late, _) = seq.scene(100);
        let drift = mean(&late) - mean(&seq.base);
        assert!((drift - 30.0).abs() < 8.0, "{drift}");
    }
}
