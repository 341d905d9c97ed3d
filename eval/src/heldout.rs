//! The held-out learning curve of a group of trainings (the seeds of one arm): at each
//! greedy-evaluation interval, the mean over seeds of the candidate's selection score minus
//! its own start's. It is what a recipe's training length and learner settings are read
//! from: a curve that still rises at the last interval asks for longer training, one that
//! stays at or below zero says the training adds nothing the start did not have.
//!
//! Pure: [`SelectionReport`]s in, points out.

use serde::Serialize;

use crate::selection::SelectionReport;

/// One interval of the curve.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CurvePoint {
    /// The interval's first agent step (a multiple of the evaluation interval).
    pub step: u64,
    /// Mean over the seeds evaluated in this interval of (score − the seed's start score).
    pub gain: f64,
    /// Seeds with a candidate in this interval.
    pub seeds: usize,
}

/// The evaluation interval of `reports`: the median of the positive gaps between successive
/// candidates of each seed (robust to an evaluation that lagged or a resume's extra one),
/// rounded to two significant digits (a configured interval is a round number; the gaps
/// differ from it by the steps an evaluation waits for); `None` with no gap.
fn interval(reports: &[SelectionReport]) -> Option<u64> {
    let mut gaps: Vec<u64> = reports
        .iter()
        .flat_map(|r| {
            r.candidates
                .windows(2)
                .map(|w| w[1].step.saturating_sub(w[0].step))
        })
        .filter(|&g| g > 0)
        .collect();
    gaps.sort_unstable();
    let gap = *gaps.get(gaps.len() / 2)?;
    let unit = 10u64.pow(gap.ilog10().saturating_sub(1));
    Some(((gap + unit / 2) / unit * unit).max(1))
}

/// The curve of `reports`, one point per interval after the start: a candidate belongs to
/// the multiple of the interval nearest its step, and a seed counts there with its last
/// candidate. A candidate nearer the start than the first interval (a resume's
/// re-evaluation of the start) and a seed whose start was never evaluated are left out.
/// Empty when no seed has a start and a later candidate.
pub fn curve(reports: &[SelectionReport]) -> Vec<CurvePoint> {
    let Some(every) = interval(reports) else {
        return Vec::new();
    };
    // (interval index, gain) of each seed's last candidate per interval.
    let mut gains: Vec<(u64, f64)> = Vec::new();
    for r in reports {
        let Some(start) = r.start_score else { continue };
        let mut last: Vec<(u64, f64)> = Vec::new();
        for c in &r.candidates {
            let k = (c.step as f64 / every as f64).round() as u64;
            if k == 0 {
                continue;
            }
            match last.last_mut() {
                Some(l) if l.0 == k => l.1 = c.score - start,
                _ => last.push((k, c.score - start)),
            }
        }
        gains.extend(last);
    }
    let mut ks: Vec<u64> = gains.iter().map(|g| g.0).collect();
    ks.sort_unstable();
    ks.dedup();
    ks.into_iter()
        .map(|k| {
            let here: Vec<f64> = gains.iter().filter(|g| g.0 == k).map(|g| g.1).collect();
            CurvePoint {
                step: k * every,
                gain: here.iter().sum::<f64>() / here.len() as f64,
                seeds: here.len(),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::selection::CandidateScore;

    fn report(start: Option<f64>, steps_scores: &[(u64, f64)]) -> SelectionReport {
        SelectionReport {
            worlds: "val".into(),
            runs: 10,
            exported_step: 0,
            exported_version: 0,
            exported_score: 0.0,
            start_score: start,
            last_step: steps_scores.last().map_or(0, |c| c.0),
            last_score: steps_scores.last().map_or(0.0, |c| c.1),
            confidence: 0.0,
            candidates: steps_scores
                .iter()
                .map(|&(step, score)| CandidateScore { step, score })
                .collect(),
        }
    }

    #[test]
    fn the_curve_averages_each_seeds_gain_over_its_own_start_per_interval() {
        // Seed 0 evaluated late once (29k) and twice at the end; seed 1 was resumed (1k).
        let a = report(
            Some(0.40),
            &[
                (0, 0.40),
                (29_000, 0.42),
                (39_990, 0.38),
                (60_010, 0.41),
                (60_020, 0.44),
            ],
        );
        let b = report(
            Some(0.30),
            &[
                (0, 0.30),
                (1_100, 0.30),
                (19_997, 0.26),
                (40_009, 0.34),
                (59_998, 0.30),
            ],
        );
        let c = curve(&[a, b]);
        let steps: Vec<u64> = c.iter().map(|p| p.step).collect();
        assert_eq!(steps, vec![20_000, 40_000, 60_000]);
        assert!((c[0].gain - (0.02 - 0.04) / 2.0).abs() < 1e-12, "{c:?}");
        assert!((c[1].gain - (-0.02 + 0.04) / 2.0).abs() < 1e-12, "{c:?}");
        // The seed's last candidate of the interval counts: 0.44, not 0.41.
        assert!((c[2].gain - (0.04 + 0.0) / 2.0).abs() < 1e-12, "{c:?}");
        assert!(c.iter().all(|p| p.seeds == 2));
    }

    #[test]
    fn a_seed_without_an_evaluated_start_is_left_out() {
        let a = report(None, &[(20_000, 0.5), (40_000, 0.6)]);
        let b = report(Some(0.2), &[(0, 0.2), (20_000, 0.1), (40_000, 0.3)]);
        let c = curve(&[a, b]);
        assert_eq!(c.len(), 2);
        assert!(c.iter().all(|p| p.seeds == 1));
        assert!((c[0].gain + 0.1).abs() < 1e-12 && (c[1].gain - 0.1).abs() < 1e-12);
        assert!(curve(&[report(Some(0.2), &[(0, 0.2)])]).is_empty());
    }
}
