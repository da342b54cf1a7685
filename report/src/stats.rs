//! Statistics over seeds: the mean with a percentile-bootstrap 95% confidence interval, the
//! interquartile mean, the first env step at which a learning curve reaches a threshold, and
//! a curve's value between its recorded points.
//!
//! Every random choice comes from a fixed seed, so a report is the same each time it is made.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Bootstrap resamples behind each interval.
pub const RESAMPLES: usize = 10_000;

/// A mean and its 95% confidence interval.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Interval {
    /// The sample mean.
    pub mean: f64,
    /// 2.5th percentile of the bootstrap means.
    pub lo: f64,
    /// 97.5th percentile of the bootstrap means.
    pub hi: f64,
}

impl Interval {
    /// Whether the two intervals share no point.
    pub fn disjoint(&self, other: &Self) -> bool {
        self.hi < other.lo || other.hi < self.lo
    }
}

/// The mean of `xs` (NaN for none).
pub fn mean(xs: &[f64]) -> f64 {
    if xs.is_empty() {
        return f64::NAN;
    }
    xs.iter().sum::<f64>() / xs.len() as f64
}

/// The value at fraction `q` of the sorted `xs`, interpolating linearly between neighbours
/// (numpy's default percentile).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let pos = q * (sorted.len() - 1) as f64;
    let (i, frac) = (pos.floor() as usize, pos - pos.floor());
    let next = sorted[(i + 1).min(sorted.len() - 1)];
    sorted[i] + frac * (next - sorted[i])
}

/// The mean of `xs` and the percentile-bootstrap 95% interval of that mean: `resamples`
/// times, draw `xs.len()` values with replacement and take their mean; the interval is the
/// 2.5th and 97.5th percentiles of those means. `None` for an empty sample.
pub fn bootstrap_mean(xs: &[f64], resamples: usize, seed: u64) -> Option<Interval> {
    if xs.is_empty() {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = xs.len();
    let mut means: Vec<f64> = (0..resamples.max(1))
        .map(|_| (0..n).map(|_| xs[rng.random_range(0..n)]).sum::<f64>() / n as f64)
        .collect();
    means.sort_by(f64::total_cmp);
    Some(Interval {
        mean: mean(xs),
        lo: quantile(&means, 0.025),
        hi: quantile(&means, 0.975),
    })
}

/// The interquartile mean: the mean of the values left after dropping the lowest and the
/// highest quarter (`floor(n / 4)` values at each end, as scipy's `trim_mean(x, 0.25)`).
/// NaN for an empty sample.
pub fn iqm(xs: &[f64]) -> f64 {
    let mut sorted = xs.to_vec();
    sorted.sort_by(f64::total_cmp);
    let cut = sorted.len() / 4;
    mean(&sorted[cut..sorted.len() - cut])
}

/// The first x of a curve whose y is at least `threshold` (the curve in increasing x).
pub fn first_reaching(curve: &[(f64, f64)], threshold: f64) -> Option<f64> {
    curve.iter().find(|p| p.1 >= threshold).map(|p| p.0)
}

/// The value of a step-wise curve at `x`: the last y recorded at or before `x` (None before
/// the first point).
pub fn value_at(curve: &[(f64, f64)], x: f64) -> Option<f64> {
    let after = curve.partition_point(|p| p.0 <= x);
    after.checked_sub(1).map(|i| curve[i].1)
}

/// The value of a curve (in increasing x) at `x`, interpolated linearly between the two
/// recorded points around it (None outside the recorded range).
pub fn interpolate(curve: &[(f64, f64)], x: f64) -> Option<f64> {
    let (first, last) = (curve.first()?, curve.last()?);
    if !(first.0..=last.0).contains(&x) {
        return None;
    }
    let after = curve.partition_point(|p| p.0 < x);
    let b = curve.get(after)?;
    match after.checked_sub(1).map(|i| curve[i]) {
        Some(a) if b.0 > a.0 => Some(a.1 + (b.1 - a.1) * (x - a.0) / (b.0 - a.0)),
        _ => Some(b.1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iqm_drops_a_quarter_at_each_end() {
        // 8 values: drop 2 low and 2 high, mean of 3, 4, 5, 6.
        assert_eq!(iqm(&[8.0, 1.0, 3.0, 100.0, 5.0, 4.0, 6.0, -50.0]), 4.5);
        // 3 values: nothing dropped.
        assert_eq!(iqm(&[1.0, 2.0, 6.0]), 3.0);
        // 10 values: drop 2 at each end.
        let xs: Vec<f64> = (1..=10).map(f64::from).collect();
        assert_eq!(iqm(&xs), 5.5);
    }

    #[test]
    fn bootstrap_of_a_constant_is_a_point() {
        let ci = bootstrap_mean(&[0.5; 10], 1000, 1).expect("a sample");
        assert_eq!((ci.mean, ci.lo, ci.hi), (0.5, 0.5, 0.5));
        assert!(bootstrap_mean(&[], 10, 1).is_none());
    }

    #[test]
    fn bootstrap_interval_matches_the_normal_approximation() {
        // Ten seeds 0, 1, ..., 9: mean 4.5, population sd 2.872, standard error 0.908; the
        // bootstrap 95% interval of the mean is close to 4.5 -/+ 1.96 * 0.908 = 4.5 -/+ 1.78.
        let xs: Vec<f64> = (0..10).map(f64::from).collect();
        let ci = bootstrap_mean(&xs, RESAMPLES, 7).expect("a sample");
        assert_eq!(ci.mean, 4.5);
        let half = 1.96 * 0.908;
        assert!((ci.lo - (4.5 - half)).abs() < 0.15, "{ci:?}");
        assert!((ci.hi - (4.5 + half)).abs() < 0.15, "{ci:?}");
        // The same seed gives the same interval.
        assert_eq!(bootstrap_mean(&xs, RESAMPLES, 7), Some(ci));
    }

    #[test]
    fn intervals_overlap_or_not() {
        let a = Interval {
            mean: 1.0,
            lo: 0.5,
            hi: 1.5,
        };
        let b = Interval {
            mean: 2.0,
            lo: 1.6,
            hi: 2.5,
        };
        let c = Interval {
            mean: 1.4,
            lo: 1.2,
            hi: 1.7,
        };
        assert!(a.disjoint(&b) && b.disjoint(&a));
        assert!(!a.disjoint(&c) && !c.disjoint(&b));
    }

    #[test]
    fn thresholds_and_steps() {
        let curve = [(100.0, 0.0), (200.0, 0.5), (300.0, 0.95), (400.0, 0.8)];
        assert_eq!(first_reaching(&curve, 0.9), Some(300.0));
        assert_eq!(first_reaching(&curve, 0.99), None);
        assert_eq!(value_at(&curve, 50.0), None);
        assert_eq!(value_at(&curve, 200.0), Some(0.5));
        assert_eq!(value_at(&curve, 299.0), Some(0.5));
        assert_eq!(value_at(&curve, 1e9), Some(0.8));
        assert_eq!(interpolate(&curve, 50.0), None);
        assert_eq!(interpolate(&curve, 100.0), Some(0.0));
        assert_eq!(interpolate(&curve, 150.0), Some(0.25));
        assert_eq!(interpolate(&curve, 350.0), Some(0.875));
        assert_eq!(interpolate(&curve, 400.0), Some(0.8));
        assert_eq!(interpolate(&curve, 401.0), None);
        assert_eq!(interpolate(&[], 1.0), None);
    }

    #[test]
    fn quantiles_interpolate() {
        let s = [0.0, 10.0, 20.0, 30.0, 40.0];
        assert_eq!(quantile(&s, 0.5), 20.0);
        assert_eq!(quantile(&s, 0.125), 5.0);
        assert_eq!(quantile(&[3.0], 0.975), 3.0);
    }
}
