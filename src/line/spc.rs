//! Trends: a bounded rolling history of per-sample statistics, individuals / moving-range
//! control limits, Cpk and Ppk against the recipe's tolerances, and Nelson's rules 1-4
//! (Western Electric's zone tests 1 and the run tests). Pure: no I/O.
//!
//! Limits come from the oldest `baseline` samples of the history (phase I), so a drift shows
//! against where the line started instead of being followed by the limits:
//! centre = mean, sigma = mean moving range / d2 (d2 = 1.128 for ranges of two),
//! UCL/LCL = centre +- 3 sigma. Cpk = min(USL - mean, mean - LSL) / (3 sigma within) with
//! the moving-range sigma; Ppk the same with the overall sample standard deviation (n - 1).

use std::collections::VecDeque;

use serde::Serialize;

use crate::record::line::{AlarmVariable, SampleRecord};

/// d2 for moving ranges of two.
pub const D2: f64 = 1.128;

/// One sample's statistics in the history.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct Point {
    /// The sample.
    pub sample_id: String,
    /// Its index.
    pub index: f64,
    /// Mean thickness, nm.
    pub thickness_mean: f64,
    /// Thickness standard deviation, nm.
    pub thickness_std: f64,
    /// Whether it passed.
    pub pass: bool,
}

impl Point {
    /// The point of a sample record (NaN where the record has null).
    pub fn of(r: &SampleRecord) -> Self {
        let f = |v: Option<f64>| v.unwrap_or(f64::NAN);
        Self {
            sample_id: r.sample_id.clone(),
            index: f(r.refractive_index),
            thickness_mean: f(r.thickness_nm.mean),
            thickness_std: f(r.thickness_nm.std),
            pass: r.verdict.passed(),
        }
    }
}

/// The rolling history, at most `capacity` points, oldest first.
#[derive(Clone, Debug)]
pub struct History {
    capacity: usize,
    points: VecDeque<Point>,
}

impl History {
    /// An empty history of at most `capacity` (at least 2) points.
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(2);
        Self {
            capacity,
            points: VecDeque::with_capacity(capacity),
        }
    }

    /// Adds a point, dropping the oldest past the capacity.
    pub fn push(&mut self, p: Point) {
        while self.points.len() >= self.capacity {
            self.points.pop_front();
        }
        self.points.push_back(p);
    }

    /// The points, oldest first.
    pub fn points(&self) -> impl DoubleEndedIterator<Item = &Point> + ExactSizeIterator {
        self.points.iter()
    }

    /// How many points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The newest point.
    pub fn last(&self) -> Option<&Point> {
        self.points.back()
    }

    /// One variable's series, oldest first.
    pub fn series(&self, v: Variable) -> Vec<f64> {
        self.points.iter().map(|p| v.of(p)).collect()
    }
}

/// A charted variable.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Variable {
    /// The index.
    RefractiveIndex,
    /// The mean thickness.
    ThicknessMeanNm,
    /// The thickness spread.
    ThicknessStdNm,
}

impl Variable {
    /// Every charted variable.
    pub const ALL: [Variable; 3] = [
        Variable::RefractiveIndex,
        Variable::ThicknessMeanNm,
        Variable::ThicknessStdNm,
    ];

    /// The variable's value in a point.
    pub fn of(self, p: &Point) -> f64 {
        match self {
            Self::RefractiveIndex => p.index,
            Self::ThicknessMeanNm => p.thickness_mean,
            Self::ThicknessStdNm => p.thickness_std,
        }
    }

    /// Its name in records.
    pub fn name(self) -> &'static str {
        match self {
            Self::RefractiveIndex => "refractive_index",
            Self::ThicknessMeanNm => "thickness_mean_nm",
            Self::ThicknessStdNm => "thickness_std_nm",
        }
    }
}

impl From<Variable> for AlarmVariable {
    fn from(v: Variable) -> Self {
        match v {
            Variable::RefractiveIndex => Self::RefractiveIndex,
            Variable::ThicknessMeanNm => Self::ThicknessMeanNm,
            Variable::ThicknessStdNm => Self::ThicknessStdNm,
        }
    }
}

/// Individuals control limits.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Limits {
    /// Centre line.
    pub center: f64,
    /// Upper control limit.
    pub ucl: f64,
    /// Lower control limit.
    pub lcl: f64,
    /// Sigma estimated from the mean moving range.
    pub sigma: f64,
    /// Mean moving range.
    pub mr_bar: f64,
    /// Points the limits come from.
    pub n: usize,
}

/// Individuals / moving-range limits of the finite `values`; `None` with fewer than two.
pub fn imr_limits(values: &[f64]) -> Option<Limits> {
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.len() < 2 {
        return None;
    }
    let center = v.iter().sum::<f64>() / v.len() as f64;
    let mr_bar = v.windows(2).map(|w| (w[1] - w[0]).abs()).sum::<f64>() / (v.len() - 1) as f64;
    let sigma = mr_bar / D2;
    Some(Limits {
        center,
        ucl: center + 3.0 * sigma,
        lcl: center - 3.0 * sigma,
        sigma,
        mr_bar,
        n: v.len(),
    })
}

/// Process capability against `[lsl, usl]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Capability {
    /// Cpk (within-sigma from the moving range).
    pub cpk: f64,
    /// Ppk (overall sample standard deviation).
    pub ppk: f64,
    /// Mean.
    pub mean: f64,
    /// Within sigma.
    pub sigma_within: f64,
    /// Overall sigma.
    pub sigma_overall: f64,
}

/// Cpk and Ppk of the finite `values` against `[lsl, usl]`; `None` with fewer than two.
pub fn capability(values: &[f64], lsl: f64, usl: f64) -> Option<Capability> {
    let l = imr_limits(values)?;
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    let mean = l.center;
    let s = (v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
    let margin = (usl - mean).min(mean - lsl);
    let ratio = |sigma: f64| {
        if sigma > 0.0 {
            margin / (3.0 * sigma)
        } else {
            f64::INFINITY
        }
    };
    Some(Capability {
        cpk: ratio(l.sigma),
        ppk: ratio(s),
        mean,
        sigma_within: l.sigma,
        sigma_overall: s,
    })
}

/// Nelson's rules 1-4.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Rule {
    /// A point beyond 3 sigma.
    Beyond3Sigma,
    /// Nine points in a row on one side of the centre line.
    NineSameSide,
    /// Six points in a row steadily rising or falling.
    SixTrending,
    /// Fourteen points in a row alternating up and down.
    FourteenAlternating,
}

impl Rule {
    /// The rule's number (1-4).
    pub fn number(self) -> u8 {
        match self {
            Self::Beyond3Sigma => 1,
            Self::NineSameSide => 2,
            Self::SixTrending => 3,
            Self::FourteenAlternating => 4,
        }
    }

    /// In words.
    pub fn text(self) -> &'static str {
        match self {
            Self::Beyond3Sigma => "a point beyond 3 sigma",
            Self::NineSameSide => "nine points in a row on one side of the centre line",
            Self::SixTrending => "six points in a row steadily rising or falling",
            Self::FourteenAlternating => "fourteen points in a row alternating up and down",
        }
    }
}

/// The rules the newest of `values` (oldest first) breaks against `limits`.
pub fn broken_rules(values: &[f64], limits: &Limits) -> Vec<Rule> {
    let mut out = Vec::new();
    let Some(&last) = values.last() else {
        return out;
    };
    if !last.is_finite() {
        return out;
    }
    if last > limits.ucl || last < limits.lcl {
        out.push(Rule::Beyond3Sigma);
    }
    let tail = |n: usize| (values.len() >= n).then(|| &values[values.len() - n..]);
    if let Some(t) = tail(9) {
        if t.iter().all(|&x| x > limits.center) || t.iter().all(|&x| x < limits.center) {
            out.push(Rule::NineSameSide);
        }
    }
    if let Some(t) = tail(6) {
        if t.windows(2).all(|w| w[1] > w[0]) || t.windows(2).all(|w| w[1] < w[0]) {
            out.push(Rule::SixTrending);
        }
    }
    if let Some(t) = tail(14) {
        let d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        if d.iter().all(|&x| x != 0.0) && d.windows(2).all(|w| (w[0] > 0.0) != (w[1] > 0.0)) {
            out.push(Rule::FourteenAlternating);
        }
    }
    out
}

/// An alarm: a rule broken by the newest sample on one variable.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Alarm {
    /// The variable.
    pub variable: Variable,
    /// The rule.
    pub rule: Rule,
    /// The value.
    pub value: f64,
    /// The limits it was judged against.
    pub limits: Limits,
}

/// Limits of one variable from the passing points among the history's oldest `baseline`
/// (a failed sample is no part of the process the limits describe), once the history
/// holds `min_points` and at least two of them passed.
pub fn limits_of(h: &History, v: Variable, baseline: usize, min_points: usize) -> Option<Limits> {
    if h.len() < min_points {
        return None;
    }
    let s: Vec<f64> = h
        .points()
        .take(baseline)
        .filter(|p| p.pass)
        .map(|p| v.of(p))
        .collect();
    imr_limits(&s)
}

/// The alarms the history's newest point raises.
pub fn alarms(h: &History, baseline: usize, min_points: usize) -> Vec<Alarm> {
    let mut out = Vec::new();
    for v in Variable::ALL {
        let Some(l) = limits_of(h, v, baseline, min_points) else {
            continue;
        };
        let s = h.series(v);
        for rule in broken_rules(&s, &l) {
            out.push(Alarm {
                variable: v,
                rule,
                value: s.last().copied().unwrap_or(f64::NAN),
                limits: l,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-5
    }

    #[test]
    fn limits_and_capability_by_hand() {
        // x = 10 12 11 13 12: mean 11.6, moving ranges 2 1 2 1 (mean 1.5), sigma 1.5/1.128.
        let x = [10.0, 12.0, 11.0, 13.0, 12.0];
        let l = imr_limits(&x).expect("limits");
        assert!(close(l.center, 11.6));
        assert!(close(l.mr_bar, 1.5));
        assert!(close(l.sigma, 1.329787));
        assert!(close(l.ucl, 15.589362));
        assert!(close(l.lcl, 7.610638));
        // LSL 8, USL 14: margin 2.4; Cpk = 2.4 / 3.989362; s = sqrt(5.2 / 4) = 1.140175.
        let c = capability(&x, 8.0, 14.0).expect("cap");
        assert!(close(c.cpk, 0.601600), "{}", c.cpk);
        assert!(close(c.sigma_overall, 1.140175));
        assert!(close(c.ppk, 0.701646), "{}", c.ppk);
        assert!(imr_limits(&[1.0]).is_none());
        assert!(imr_limits(&[1.0, f64::NAN]).is_none());
    }

    fn lim() -> Limits {
        Limits {
            center: 0.0,
            ucl: 3.0,
            lcl: -3.0,
            sigma: 1.0,
            mr_bar: D2,
            n: 25,
        }
    }

    #[test]
    fn rule_1_beyond_three_sigma() {
        assert_eq!(broken_rules(&[0.5, 3.1], &lim()), vec![Rule::Beyond3Sigma]);
        assert_eq!(broken_rules(&[0.5, -3.5], &lim()), vec![Rule::Beyond3Sigma]);
        assert!(broken_rules(&[0.5, 2.9], &lim()).is_empty());
    }

    #[test]
    fn rule_2_nine_on_one_side() {
        let mut x = vec![0.5, -0.2, 0.3, -0.1, 0.2, -0.3, 0.1, 0.4];
        x.push(0.3);
        // Eight on the positive side at most so far: no alarm.
        assert!(!broken_rules(&x, &lim()).contains(&Rule::NineSameSide));
        let y = [-1.0, 0.1, 0.2, 0.1, 0.3, 0.2, 0.4, 0.1, 0.2, 0.3];
        assert_eq!(broken_rules(&y, &lim()), vec![Rule::NineSameSide]);
        let z: Vec<f64> = y.iter().map(|v| -v).collect();
        assert_eq!(broken_rules(&z, &lim()), vec![Rule::NineSameSide]);
    }

    #[test]
    fn rule_3_six_trending() {
        let x = [0.0, -0.5, -0.4, -0.3, 0.2, 0.3, 0.4];
        assert_eq!(broken_rules(&x, &lim()), vec![Rule::SixTrending]);
        let x = [0.0, -0.5, -0.4, -0.3, 0.2, 0.2, 0.4]; // a tie breaks the run
        assert!(broken_rules(&x, &lim()).is_empty());
        let x = [1.0, 0.8, 0.5, 0.1, -0.2, -0.4];
        assert_eq!(broken_rules(&x, &lim()), vec![Rule::SixTrending]);
    }

    #[test]
    fn rule_4_fourteen_alternating() {
        let x: Vec<f64> = (0..14)
            .map(|i| if i % 2 == 0 { 0.5 } else { -0.5 })
            .collect();
        assert_eq!(broken_rules(&x, &lim()), vec![Rule::FourteenAlternating]);
        assert!(broken_rules(&x[1..], &lim()).is_empty());
    }

    #[test]
    fn history_is_bounded_and_limits_come_from_its_start() {
        let mut h = History::new(5);
        for i in 0..8 {
            h.push(Point {
                sample_id: format!("s{i}"),
                index: 2.1,
                thickness_mean: f64::from(i),
                thickness_std: 1.0,
                pass: true,
            });
        }
        assert_eq!(h.len(), 5);
        assert_eq!(h.points().next().map(|p| p.sample_id.as_str()), Some("s3"));
        // Limits from the oldest three: 3 4 5: centre 4, MR-bar 1.
        let l = limits_of(&h, Variable::ThicknessMeanNm, 3, 5).expect("limits");
        assert!(close(l.center, 4.0) && close(l.mr_bar, 1.0));
        assert!(limits_of(&h, Variable::ThicknessMeanNm, 3, 6).is_none());
        // A failed sample among them is left out of the limits: 3 _ 5 -> centre 4, MR-bar 2.
        let mut g = h.clone();
        if let Some(p) = g.points.get_mut(1) {
            p.pass = false;
        }
        let l = limits_of(&g, Variable::ThicknessMeanNm, 3, 5).expect("limits");
        assert!(close(l.center, 4.0) && close(l.mr_bar, 2.0) && l.n == 2);
        // Newest 7 is beyond 4 + 3 / 1.128 = 6.66; and 3..7 rises five times only.
        let a = alarms(&h, 3, 5);
        assert_eq!(a.len(), 1, "{a:?}");
        assert_eq!(a[0].rule, Rule::Beyond3Sigma);
        assert_eq!(a[0].variable, Variable::ThicknessMeanNm);
    }
}
