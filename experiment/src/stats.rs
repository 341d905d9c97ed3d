//! Paired statistics of an experiment: ADP against a control on the same worlds and the same
//! run seeds. Pure functions, no I/O.
//!
//! * **Per-world differences** ([`paired_differences`]): for each world, the ADP value minus
//!   the control's (success rate or score after trimming).
//! * **Bootstrap interval** ([`bootstrap_mean`]): the percentile bootstrap of the mean
//!   difference over worlds: `resamples` times, draw as many worlds as there are with
//!   replacement (a seeded SplitMix64 stream, so a report is reproducible) and take the mean;
//!   the interval is the `(1 - c)/2` and `(1 + c)/2` order statistics of those means
//!   (`sorted[floor(B (1 - c) / 2)]` and `sorted[ceil(B (1 + c) / 2) - 1]`).
//! * **McNemar's test** ([`mcnemar`]) on paired success outcomes: with `b` pairs where only
//!   ADP succeeded and `c` where only the control did, the exact two-sided binomial p-value
//!   `min(1, 2 P(X <= min(b, c)))`, `X ~ Bin(b + c, 1/2)`, and the chi-square statistic with
//!   continuity correction `(|b - c| - 1)^2 / (b + c)` with its p-value on one degree of
//!   freedom.

use serde::{Deserialize, Serialize};

/// `a[i] - b[i]` for every world `i`.
///
/// # Panics
/// If the slices differ in length (the caller pairs worlds).
pub fn paired_differences(a: &[f64], b: &[f64]) -> Vec<f64> {
    assert_eq!(a.len(), b.len(), "paired values of the same worlds");
    a.iter().zip(b).map(|(x, y)| x - y).collect()
}

/// Arithmetic mean (0 for no values).
pub fn mean(x: &[f64]) -> f64 {
    if x.is_empty() {
        0.0
    } else {
        x.iter().sum::<f64>() / x.len() as f64
    }
}

/// Sample standard deviation (n - 1 in the denominator; 0 for fewer than two values).
pub fn sample_sd(x: &[f64]) -> f64 {
    if x.len() < 2 {
        return 0.0;
    }
    let m = mean(x);
    (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (x.len() - 1) as f64).sqrt()
}

/// A mean with its percentile-bootstrap interval.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Interval {
    /// Values (worlds).
    pub n: usize,
    /// The mean of the values.
    pub mean: f64,
    /// Lower end of the interval.
    pub lo: f64,
    /// Upper end of the interval.
    pub hi: f64,
    /// Confidence level, e.g. 0.95.
    pub confidence: f64,
}

/// Where an interval lies against 0: what a difference's verdict says in words.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// The whole interval is above 0.
    Above,
    /// The whole interval is below 0.
    Below,
    /// The interval holds 0: no difference resolved.
    Holds,
}

impl Interval {
    /// Where the interval lies against 0.
    pub fn side(&self) -> Side {
        if self.lo > 0.0 {
            Side::Above
        } else if self.hi < 0.0 {
            Side::Below
        } else {
            Side::Holds
        }
    }
}

/// SplitMix64: a tiny, well-mixed, seedable generator (Steele et al. 2014), enough for
/// resampling indices.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator seeded with `seed`.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// A uniform index in `0..n` (`n > 0`; Lemire's multiply-shift, bias below 2^-32 for the
    /// sizes used here).
    pub fn below(&mut self, n: usize) -> usize {
        ((u128::from(self.next_u64()) * n as u128) >> 64) as usize
    }
}

/// The mean of `values` with its percentile-bootstrap interval at `confidence` from
/// `resamples` seeded resamples (see the module docs). No values give a zero interval.
pub fn bootstrap_mean(values: &[f64], resamples: usize, confidence: f64, seed: u64) -> Interval {
    let n = values.len();
    let m = mean(values);
    if n == 0 || resamples == 0 {
        return Interval {
            n,
            mean: m,
            lo: m,
            hi: m,
            confidence,
        };
    }
    let mut rng = SplitMix64::new(seed);
    let mut means: Vec<f64> = (0..resamples)
        .map(|_| (0..n).map(|_| values[rng.below(n)]).sum::<f64>() / n as f64)
        .collect();
    means.sort_by(f64::total_cmp);
    let (lo, hi) = percentile_bounds(resamples, confidence);
    Interval {
        n,
        mean: m,
        lo: means[lo],
        hi: means[hi],
        confidence,
    }
}

/// The mean of a seeds x worlds table of paired differences (`values[s][w]`, every row as
/// long) with its two-level percentile-bootstrap interval: each resample draws the seeds with
/// replacement, then the worlds with replacement, and averages the drawn cells, so the
/// interval counts how much training seeds differ as well as worlds. With one seed it is
/// [`bootstrap_mean`] over the worlds (with the same resamples for the same seed).
pub fn bootstrap_seeds_and_worlds(
    values: &[Vec<f64>],
    resamples: usize,
    confidence: f64,
    seed: u64,
) -> Interval {
    let s = values.len();
    let w = values.first().map_or(0, Vec::len);
    let all: Vec<f64> = values.iter().flatten().copied().collect();
    let m = mean(&all);
    if s <= 1 || w == 0 || resamples == 0 {
        return bootstrap_mean(
            values.first().map_or(&[][..], Vec::as_slice),
            resamples,
            confidence,
            seed,
        );
    }
    let mut rng = SplitMix64::new(seed);
    let mut drawn = vec![0usize; s];
    let mut means: Vec<f64> = (0..resamples)
        .map(|_| {
            for d in drawn.iter_mut() {
                *d = rng.below(s);
            }
            let mut sum = 0.0;
            for _ in 0..w {
                let world = rng.below(w);
                sum += drawn.iter().map(|&k| values[k][world]).sum::<f64>();
            }
            sum / (s * w) as f64
        })
        .collect();
    means.sort_by(f64::total_cmp);
    let (lo, hi) = percentile_bounds(resamples, confidence);
    Interval {
        n: w,
        mean: m,
        lo: means[lo],
        hi: means[hi],
        confidence,
    }
}

/// Indices of the lower and upper ends of a percentile interval at `confidence` among
/// `b >= 1` sorted values: `floor(b (1 - c) / 2)` and `ceil(b (1 + c) / 2) - 1`, within
/// `0..b`.
pub fn percentile_bounds(b: usize, confidence: f64) -> (usize, usize) {
    let tail = (1.0 - confidence) / 2.0;
    // The tolerance keeps decimal levels exact: (1 - 0.9) / 2 x 100 is 4.999... in binary.
    let lo = ((b as f64 * tail + 1e-9).floor() as usize).min(b - 1);
    let hi = ((b as f64 * (1.0 - tail) - 1e-9).ceil() as usize)
        .saturating_sub(1)
        .clamp(lo, b - 1);
    (lo, hi)
}

/// McNemar's test on paired binary outcomes (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct McNemar {
    /// Pairs compared.
    pub n: usize,
    /// Pairs where ADP succeeded and the control failed.
    pub adp_only: usize,
    /// Pairs where the control succeeded and ADP failed.
    pub control_only: usize,
    /// Exact two-sided binomial p-value.
    pub p_exact: f64,
    /// Chi-square statistic with continuity correction (0 without discordant pairs).
    pub chi2: f64,
    /// Its p-value on one degree of freedom.
    pub p_chi2: f64,
}

/// McNemar's test of paired outcomes `(adp_succeeded, control_succeeded)`.
pub fn mcnemar(pairs: impl IntoIterator<Item = (bool, bool)>) -> McNemar {
    let (mut n, mut b, mut c) = (0, 0, 0);
    for (a, k) in pairs {
        n += 1;
        match (a, k) {
            (true, false) => b += 1,
            (false, true) => c += 1,
            _ => {}
        }
    }
    let d = b + c;
    let (p_exact, chi2, p_chi2) = if d == 0 {
        (1.0, 0.0, 1.0)
    } else {
        let k = b.min(c);
        let tail: f64 = (0..=k).map(|i| binomial_half_pmf(d, i)).sum();
        let chi2 = ((b as f64 - c as f64).abs() - 1.0).max(0.0).powi(2) / d as f64;
        ((2.0 * tail).min(1.0), chi2, chi2_sf_1df(chi2))
    };
    McNemar {
        n,
        adp_only: b,
        control_only: c,
        p_exact,
        chi2,
        p_chi2,
    }
}

/// `C(n, k) / 2^n`, computed in logs so large `n` neither overflows nor underflows early.
fn binomial_half_pmf(n: usize, k: usize) -> f64 {
    (ln_choose(n, k) - n as f64 * std::f64::consts::LN_2).exp()
}

/// `ln C(n, k)` as a sum of logs (exact enough for the pair counts of an experiment).
fn ln_choose(n: usize, k: usize) -> f64 {
    let k = k.min(n - k);
    (0..k)
        .map(|i| ((n - i) as f64).ln() - ((i + 1) as f64).ln())
        .sum()
}

/// Upper tail of the chi-square distribution with one degree of freedom:
/// `P(X > x) = erfc(sqrt(x / 2))`.
pub fn chi2_sf_1df(x: f64) -> f64 {
    if x <= 0.0 {
        1.0
    } else {
        erfc((x / 2.0).sqrt())
    }
}

/// The complementary error function, `erfc(x)` for `x >= 0`, from the Chebyshev-fitted
/// approximation of Numerical Recipes (`erfcc`, relative error below 1.2e-7).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let r = t * poly.exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

#[cfg(test)]
mod tests {

    /// Seeds that disagree widen the two-level interval; seeds that agree give the worlds'
    /// interval; one seed is the one-level bootstrap.
    #[test]
    fn the_two_level_bootstrap_counts_the_seeds() {
        let mut rng = SplitMix64::new(7);
        let worlds: Vec<f64> = (0..200)
            .map(|_| (rng.below(1000) as f64 / 1000.0 - 0.5) * 0.1)
            .collect();
        let same = vec![worlds.clone(), worlds.clone(), worlds.clone()];
        let apart: Vec<Vec<f64>> = [-0.03, 0.0, 0.03]
            .iter()
            .map(|o| worlds.iter().map(|x| x + o).collect())
            .collect();
        let one = bootstrap_mean(&worlds, 4000, 0.95, 1);
        let a = bootstrap_seeds_and_worlds(&same, 4000, 0.95, 1);
        let b = bootstrap_seeds_and_worlds(&apart, 4000, 0.95, 1);
        assert!((a.mean - one.mean).abs() < 1e-12 && (b.mean - one.mean).abs() < 1e-12);
        assert!(((a.hi - a.lo) - (one.hi - one.lo)).abs() < 0.25 * (one.hi - one.lo));
        assert!(b.hi - b.lo > 2.0 * (one.hi - one.lo), "{b:?} against {one:?}");
        assert_eq!(
            bootstrap_seeds_and_worlds(std::slice::from_ref(&worlds), 4000, 0.95, 1),
            one
        );
    }

    use super::*;

    #[test]
    fn differences_mean_and_sd_by_hand() {
        let d = paired_differences(&[0.5, 0.25, 1.0], &[0.25, 0.5, 0.0]);
        assert_eq!(d, vec![0.25, -0.25, 1.0]);
        assert!((mean(&d) - 1.0 / 3.0).abs() < 1e-15);
        // Deviations 1/12 - 1/3 ... : sum of squares (0.25-1/3)^2 + (-0.25-1/3)^2 + (2/3)^2
        // = 1/144 + 49/144 + 64/144 = 114/144; / 2 = 0.395833..; sqrt = 0.629153...
        assert!((sample_sd(&d) - (114.0f64 / 288.0).sqrt()).abs() < 1e-15);
        assert_eq!(sample_sd(&[3.0]), 0.0);
    }

    #[test]
    fn percentile_bounds_by_hand() {
        // 10000 resamples at 95 %: the 250th and the 9750th values (indices 250 and 9749).
        assert_eq!(percentile_bounds(10_000, 0.95), (250, 9749));
        assert_eq!(percentile_bounds(100, 0.9), (5, 94));
        assert_eq!(percentile_bounds(1, 0.95), (0, 0));
    }

    #[test]
    fn bootstrap_of_a_constant_is_the_constant() {
        let i = bootstrap_mean(&[0.25; 7], 1000, 0.95, 1);
        assert_eq!((i.n, i.mean, i.lo, i.hi), (7, 0.25, 0.25, 0.25));
    }

    /// Two worlds with differences 0 and 1: a resample's mean is 0, 1/2 or 1 with
    /// probabilities 1/4, 1/2, 1/4, so the 95 % interval is [0, 1] and the share of
    /// resamples at 1/2 is about one half.
    #[test]
    fn bootstrap_of_two_values_by_hand() {
        let i = bootstrap_mean(&[0.0, 1.0], 10_000, 0.95, 7);
        assert_eq!((i.mean, i.lo, i.hi), (0.5, 0.0, 1.0));
        let mut rng = SplitMix64::new(7);
        let halves = (0..10_000).filter(|_| rng.below(2) + rng.below(2) == 1).count();
        assert!((4800..5200).contains(&halves), "{halves}");
        // A 40 % interval (the 3000th to 7000th means) excludes both ends: [1/2, 1/2].
        let i = bootstrap_mean(&[0.0, 1.0], 10_000, 0.4, 7);
        assert_eq!((i.lo, i.hi), (0.5, 0.5));
        // Seeded: the same seed gives the same interval.
        let v = [0.1, -0.3, 0.7, 0.2, 0.0];
        assert_eq!(bootstrap_mean(&v, 500, 0.95, 3), bootstrap_mean(&v, 500, 0.95, 3));
    }

    #[test]
    fn mcnemar_by_hand() {
        // b = 10, c = 2: exact p = 2 (C(12,0) + C(12,1) + C(12,2)) / 2^12 = 2 x 79 / 4096.
        let pairs = std::iter::repeat_n((true, false), 10)
            .chain(std::iter::repeat_n((false, true), 2))
            .chain(std::iter::repeat_n((true, true), 30))
            .chain(std::iter::repeat_n((false, false), 3));
        let m = mcnemar(pairs);
        assert_eq!((m.n, m.adp_only, m.control_only), (45, 10, 2));
        assert!((m.p_exact - 158.0 / 4096.0).abs() < 1e-12, "{}", m.p_exact);
        // chi2 = (|10 - 2| - 1)^2 / 12 = 49 / 12; P(chi2_1 > 4.0833) = 0.043308 (tables).
        assert!((m.chi2 - 49.0 / 12.0).abs() < 1e-12);
        assert!((m.p_chi2 - 0.043_308).abs() < 2e-5, "{}", m.p_chi2);
        // No discordant pairs: nothing to test.
        let m = mcnemar([(true, true), (false, false)]);
        assert_eq!((m.p_exact, m.chi2, m.p_chi2), (1.0, 0.0, 1.0));
        // b = c = 1: exact p = min(1, 2 x 3/4) = 1; the corrected |b - c| - 1 is floored at 0.
        let m = mcnemar([(true, false), (false, true)]);
        assert_eq!((m.p_exact, m.chi2, m.p_chi2), (1.0, 0.0, 1.0));
        // b = 4, c = 0: exact p = 2 / 16; chi2 = 9 / 4 with p = 0.133614 (tables).
        let m = mcnemar(std::iter::repeat_n((true, false), 4));
        assert!((m.p_exact - 0.125).abs() < 1e-15 && (m.chi2 - 2.25).abs() < 1e-15);
        assert!((m.p_chi2 - 0.133_614).abs() < 2e-5, "{}", m.p_chi2);
    }

    #[test]
    fn chi_square_tail_at_known_quantiles() {
        // 3.841459 is the 95th percentile of chi-square with 1 df; 6.634897 the 99th.
        assert!((chi2_sf_1df(3.841_459) - 0.05).abs() < 1e-6);
        assert!((chi2_sf_1df(6.634_897) - 0.01).abs() < 1e-6);
        assert_eq!(chi2_sf_1df(0.0), 1.0);
    }
}
