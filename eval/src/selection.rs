//! Held-out selection (`[greedy] select`): every greedy evaluation of a training run is a
//! candidate, the start policy (step 0) included, and the run exports the candidate with the
//! best mean score on the greedy worlds instead of its last policy.
//!
//! [`Selection`] is the pure choice: the best mean score wins, and on a tie the earliest
//! agent step, so a run whose policy never beats its start exports its start. With a gate
//! (`[greedy] select_confidence`), a later policy must also beat the start on the greedy
//! worlds by more than their noise: the lower bound of its paired gain over the start (a
//! percentile bootstrap over the worlds, [`gain_lower_bound`]) must be above zero. The
//! [`GreedyMonitor`](crate::greedy::GreedyMonitor) keeps one and persists it in the run
//! directory's [`SELECTION_DIR`] (its candidates in [`STATE_FILE`], the best policy's weights
//! and the start's as little-endian `f32` files), so a resumed run still knows its best
//! candidate. At the end, [`Chosen::export`] writes the best policy over `export/` and
//! [`REPORT_FILE`] (a [`SelectionReport`]) into the run directory and `export/`.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use learner::export::{export_published, Published};
use planner::ActionSpace;

use crate::error::{Error, Result};

/// The directory of the selection's state in the run directory.
pub const SELECTION_DIR: &str = "selection";
/// The candidates so far, in [`SELECTION_DIR`] (a [`SelectionState`]).
pub const STATE_FILE: &str = "state.json";
/// The start policy's weights, in [`SELECTION_DIR`] (kept until it is evaluated).
pub const START_WEIGHTS: &str = "start.f32";
/// The report written into the run directory and into `export/`.
pub const REPORT_FILE: &str = "selection.json";

/// One candidate: a policy evaluated on the greedy worlds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Candidate {
    /// Agent steps stored when the policy was taken (0: the start policy).
    pub agent_steps: u64,
    /// Its policy version.
    pub policy_version: u64,
    /// Gradient updates done when it was taken.
    pub updates: u64,
    /// Mean BARN score on the greedy worlds (what selection compares).
    pub score: f64,
    /// Success rate there (%).
    pub success: f64,
    /// Its mean score per greedy world, in the worlds' order (what the gate pairs with the
    /// start's; empty in a state written before they were kept).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub world_scores: Vec<f64>,
}

/// The candidates of a run and the index of the best: pure bookkeeping.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Selection {
    /// Every candidate, in the order offered.
    pub candidates: Vec<Candidate>,
    /// Index of the best in `candidates` (`None` before the first).
    pub best: Option<usize>,
    /// The gate's confidence in (0, 1) (0: no gate, the best mean wins).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub confidence: f64,
}

/// Whether `x` is zero (serde's `skip_serializing_if`).
fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// Bootstrap resamples of [`gain_lower_bound`].
const RESAMPLES: usize = 10_000;

/// The lower end of the `confidence` percentile-bootstrap interval (one-sided) of the mean of
/// `gains` (one paired gain per world), resampling the worlds with a fixed seed, so the same
/// gains always give the same bound. `-inf` for no gains. Pure.
pub fn gain_lower_bound(gains: &[f64], confidence: f64) -> f64 {
    let n = gains.len();
    if n == 0 {
        return f64::NEG_INFINITY;
    }
    // splitmix64: a small seeded stream, enough to draw world indices.
    let mut state: u64 = 0x5e1e_c710_0000_0001;
    let mut next = move || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    };
    let mut means: Vec<f64> = (0..RESAMPLES)
        .map(|_| (0..n).map(|_| gains[(next() % n as u64) as usize]).sum::<f64>() / n as f64)
        .collect();
    means.sort_by(f64::total_cmp);
    let k = (((1.0 - confidence) * RESAMPLES as f64).floor() as usize).min(RESAMPLES - 1);
    means[k]
}

impl Selection {
    /// A selection whose later policies must clear the gate at `confidence` (0: none).
    pub fn gated(confidence: f64) -> Self {
        Self {
            confidence,
            ..Self::default()
        }
    }

    /// Adds `c` and returns whether it is the new best: a higher mean score than the best
    /// so far, or an equal one at an earlier agent step (the earliest wins ties, whatever
    /// order the candidates come in). With a gate, a candidate after the start must also
    /// clear it ([`Selection::clears_gate`]).
    pub fn offer(&mut self, c: Candidate) -> bool {
        let better = self.clears_gate(&c)
            && match self.best() {
                None => true,
                Some(b) => c.score > b.score || (c.score == b.score && c.agent_steps < b.agent_steps),
            };
        self.candidates.push(c);
        if better {
            self.best = Some(self.candidates.len() - 1);
        }
        better
    }

    /// The best candidate so far.
    pub fn best(&self) -> Option<&Candidate> {
        self.best.map(|i| &self.candidates[i])
    }

    /// Whether `c` may be exported: always without a gate and for the start; with one, only
    /// when the start was evaluated on the same worlds first and the lower bound of `c`'s
    /// paired gain over it is above zero. A candidate offered before the start (a resumed
    /// run's) never clears it: its weights are not kept for a later verdict.
    pub fn clears_gate(&self, c: &Candidate) -> bool {
        if self.confidence <= 0.0 || c.agent_steps == 0 {
            return true;
        }
        let Some(start) = self.start() else {
            return false;
        };
        if start.world_scores.len() != c.world_scores.len() || c.world_scores.is_empty() {
            return false;
        }
        let gains: Vec<f64> = (c.world_scores.iter().zip(&start.world_scores))
            .map(|(a, b)| a - b)
            .collect();
        gain_lower_bound(&gains, self.confidence) > 0.0
    }

    /// The start policy's candidate (agent step 0), once evaluated.
    pub fn start(&self) -> Option<&Candidate> {
        self.candidates.iter().find(|c| c.agent_steps == 0)
    }

    /// The last policy's candidate: the one of the most agent steps (the latest offered of
    /// those).
    pub fn last(&self) -> Option<&Candidate> {
        // `max_by_key` gives the last of equal maxima: the latest offered.
        self.candidates.iter().max_by_key(|c| c.agent_steps)
    }

    /// What the run exports and why, once there is a candidate.
    pub fn report(&self, worlds: &str, runs: usize) -> Option<SelectionReport> {
        let best = self.best()?;
        let last = self.last()?;
        Some(SelectionReport {
            worlds: worlds.to_owned(),
            runs,
            exported_step: best.agent_steps,
            exported_version: best.policy_version,
            exported_score: best.score,
            start_score: self.start().map(|c| c.score),
            last_step: last.agent_steps,
            last_score: last.score,
            confidence: self.confidence,
            candidates: self
                .candidates
                .iter()
                .map(|c| CandidateScore {
                    step: c.agent_steps,
                    score: c.score,
                })
                .collect(),
        })
    }
}

/// One candidate in a [`SelectionReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CandidateScore {
    /// Its agent step.
    pub step: u64,
    /// Its mean score on the selection worlds.
    pub score: f64,
}

/// [`REPORT_FILE`]: which policy a run exported and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SelectionReport {
    /// The selection worlds (`[greedy] worlds`).
    pub worlds: String,
    /// Runs per world (`[greedy] runs`).
    pub runs: usize,
    /// The agent step of the exported policy (0: the start).
    pub exported_step: u64,
    /// Its policy version.
    pub exported_version: u64,
    /// Its mean score on the selection worlds.
    pub exported_score: f64,
    /// The start policy's mean score (`null` when the run's start was never evaluated, e.g. a
    /// run that turned selection on when resumed).
    pub start_score: Option<f64>,
    /// The last policy's agent step.
    pub last_step: u64,
    /// The last policy's mean score.
    pub last_score: f64,
    /// The gate's confidence (`[greedy] select_confidence`; absent: no gate).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub confidence: f64,
    /// Every candidate, in the order evaluated.
    pub candidates: Vec<CandidateScore>,
}

/// One line for the log: which step was exported and how it compares with the start.
pub fn describe(r: &SelectionReport) -> String {
    let against = match r.start_score {
        Some(s) if r.exported_step == 0 => format!(
            "the start itself: no later policy beat its {s:.4}{} (last policy, step {}: {:.4})",
            if r.confidence > 0.0 {
                format!(
                    " with a paired lower bound above zero at {:.0} %",
                    100.0 * r.confidence
                )
            } else {
                String::new()
            },
            r.last_step,
            r.last_score
        ),
        Some(s) => format!(
            "{:+.4} over the start's {s:.4} (last policy, step {}: {:.4})",
            r.exported_score - s,
            r.last_step,
            r.last_score
        ),
        None => format!(
            "the start was not evaluated (last policy, step {}: {:.4})",
            r.last_step, r.last_score
        ),
    };
    format!(
        "selection on {} ({} run(s) per world, {} candidates): exported the policy of step {} \
         (mean score {:.4}), {against}",
        r.worlds,
        r.runs,
        r.candidates.len(),
        r.exported_step,
        r.exported_score
    )
}

/// [`STATE_FILE`]: the selection as persisted, with what makes its scores comparable.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SelectionState {
    /// The world ids evaluated on.
    pub worlds: Vec<usize>,
    /// Runs per world.
    pub runs: usize,
    /// The policies' layer sizes.
    pub dims: Vec<usize>,
    /// The candidates.
    pub selection: Selection,
    /// The file in [`SELECTION_DIR`] holding the best candidate's weights.
    pub best_weights: Option<String>,
}

/// The best policy of a finished selection: what [`Chosen::export`] writes.
#[derive(Debug, Clone)]
pub struct Chosen {
    /// The report.
    pub report: SelectionReport,
    /// The best candidate.
    pub candidate: Candidate,
    /// Its flat weights.
    pub weights: Vec<f32>,
}

impl Chosen {
    /// Writes the chosen policy over `<run_dir>/export` (the run's final `checkpoint` gives
    /// its run id, network sizes and environment; the card's counters are the candidate's)
    /// and [`REPORT_FILE`] into the run directory and `export/`. Returns the export
    /// directory.
    pub fn export(&self, checkpoint: &Path, run_dir: &Path, space: ActionSpace) -> Result<PathBuf> {
        let out = run_dir.join("export");
        let c = &self.candidate;
        export_published(
            checkpoint,
            &out,
            space,
            &Published {
                weights: &self.weights,
                policy_version: c.policy_version,
                inserts: c.agent_steps,
                updates: c.updates,
            },
        )
        .map_err(|e| Error::component("held-out selection: export", e))?;
        let mut json = serde_json::to_vec_pretty(&self.report).expect("a report serializes");
        json.push(b'\n');
        for dir in [run_dir, out.as_path()] {
            write_atomic(&dir.join(REPORT_FILE), &json)?;
        }
        Ok(out)
    }
}

/// Writes `bytes` to `path` through a temporary file and a rename.
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|e| Error::io("write", path, e))
}

/// Writes flat weights as little-endian `f32`.
pub(crate) fn write_weights(path: &Path, weights: &[f32]) -> Result<()> {
    let bytes: Vec<u8> = weights.iter().flat_map(|w| w.to_le_bytes()).collect();
    write_atomic(path, &bytes)
}

/// Reads flat weights written by [`write_weights`]; refuses a file of another length than
/// `count` values.
pub(crate) fn read_weights(path: &Path, count: usize) -> Result<Vec<f32>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io("read", path, e))?;
    if bytes.len() != 4 * count {
        return Err(Error::Refused(format!(
            "{}: {} bytes, but the policy has {count} parameters ({} bytes)",
            path.display(),
            bytes.len(),
            4 * count
        )));
    }
    Ok(bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn offer_all(scores: &[(u64, f64)]) -> Selection {
        let mut s = Selection::default();
        for &(step, score) in scores {
            s.offer(Candidate {
                agent_steps: step,
                policy_version: step / 100,
                updates: step,
                score,
                success: 100.0 * score,
                world_scores: Vec::new(),
            });
        }
        s
    }

    fn candidate(step: u64, world_scores: Vec<f64>) -> Candidate {
        Candidate {
            agent_steps: step,
            policy_version: step / 100,
            updates: step,
            score: world_scores.iter().sum::<f64>() / world_scores.len() as f64,
            success: 100.0,
            world_scores,
        }
    }

    /// With the gate, a later policy whose higher mean is within the worlds' noise keeps the
    /// start exported; one that beats the start on nearly every world is exported; without
    /// it the higher mean wins whatever its noise.
    #[test]
    fn the_gate_exports_only_gains_above_the_noise() {
        let start: Vec<f64> = (0..15).map(|w| 0.40 + 0.01 * (w % 5) as f64).collect();
        // +0.01 on average: +0.15 on one world, -0.01 or 0 on the others.
        let noisy: Vec<f64> = (start.iter().enumerate())
            .map(|(w, s)| {
                s + if w == 0 {
                    0.15
                } else if w % 2 == 0 {
                    -0.01
                } else {
                    0.0
                }
            })
            .collect();
        // +0.02 on every world but one.
        let steady: Vec<f64> = (start.iter().enumerate())
            .map(|(w, s)| s + if w == 3 { -0.005 } else { 0.02 })
            .collect();
        let mut gated = Selection::gated(0.95);
        assert!(gated.offer(candidate(0, start.clone())));
        assert!(!gated.offer(candidate(20_000, noisy.clone())));
        assert_eq!(gated.best().unwrap().agent_steps, 0);
        let r = gated.report("train", 10).unwrap();
        assert!(
            describe(&r).contains("paired lower bound above zero at 95 %"),
            "{}",
            describe(&r)
        );
        assert!(gated.offer(candidate(40_000, steady)));
        assert_eq!(gated.best().unwrap().agent_steps, 40_000);
        let mut plain = Selection::default();
        plain.offer(candidate(0, start));
        assert!(plain.offer(candidate(20_000, noisy)));
        // Before its start was evaluated (a resumed run), no later policy clears the gate.
        let mut early = Selection::gated(0.95);
        assert!(!early.offer(candidate(20_000, vec![0.9; 15])));
        assert!(early.best().is_none());
    }

    /// The bound is a percentile of resampled means: below the mean, above zero only for
    /// gains that are steadily positive, and the same on every call.
    #[test]
    fn the_gain_bound_is_a_seeded_percentile() {
        let steady = [0.02; 10];
        assert!((gain_lower_bound(&steady, 0.95) - 0.02).abs() < 1e-12);
        let mixed = [0.1, -0.1, 0.05, -0.05, 0.0, 0.02];
        let b = gain_lower_bound(&mixed, 0.95);
        assert!(b < 0.0 && b > -0.1, "{b}");
        assert_eq!(b, gain_lower_bound(&mixed, 0.95));
        assert!(gain_lower_bound(&mixed, 0.5) > b);
        assert_eq!(gain_lower_bound(&[], 0.95), f64::NEG_INFINITY);
    }

    /// A training whose policy only gets worse on the selection worlds exports its start.
    #[test]
    fn a_run_that_only_gets_worse_exports_its_start() {
        let s = offer_all(&[(0, 0.47), (5000, 0.46), (10000, 0.44), (15000, 0.40)]);
        assert_eq!(s.best().unwrap().agent_steps, 0);
        let r = s.report("val", 1).unwrap();
        assert_eq!((r.exported_step, r.exported_score), (0, 0.47));
        assert_eq!(
            (r.start_score, r.last_step, r.last_score),
            (Some(0.47), 15000, 0.40)
        );
        assert_eq!(r.candidates.len(), 4);
        assert!(
            describe(&r).contains("exported the policy of step 0"),
            "{}",
            describe(&r)
        );
        // One that improves exports its best, not its last.
        let s = offer_all(&[(0, 0.40), (5000, 0.46), (10000, 0.44)]);
        let r = s.report("val", 2).unwrap();
        assert_eq!(r.exported_step, 5000);
        assert!(
            describe(&r).contains("+0.0600 over the start's 0.4000"),
            "{}",
            describe(&r)
        );
    }

    /// Ties go to the earlier candidate, also when the earlier one is offered later (the
    /// start of a resumed run evaluated after other candidates).
    #[test]
    fn ties_go_to_the_earlier_candidate() {
        let s = offer_all(&[(0, 0.45), (5000, 0.47), (10000, 0.47), (15000, 0.45)]);
        assert_eq!(s.best().unwrap().agent_steps, 5000);
        let s = offer_all(&[(0, 0.45), (5000, 0.45)]);
        assert_eq!(s.best().unwrap().agent_steps, 0);
        let mut s = offer_all(&[(5000, 0.45), (10000, 0.45)]);
        assert_eq!(s.best().unwrap().agent_steps, 5000);
        assert!(s.offer(Candidate {
            agent_steps: 0,
            policy_version: 0,
            updates: 0,
            score: 0.45,
            success: 90.0,
            world_scores: Vec::new(),
        }));
        assert_eq!(s.best().unwrap().agent_steps, 0);
        assert_eq!(s.last().unwrap().agent_steps, 10000);
        assert!(Selection::default().report("val", 1).is_none());
    }

    #[test]
    fn weights_files_round_trip_and_refuse_another_size() {
        let dir = std::env::temp_dir().join(format!("adp-selection-weights-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("w.f32");
        write_weights(&path, &[1.0, -2.5, 3.25]).unwrap();
        assert_eq!(read_weights(&path, 3).unwrap(), [1.0, -2.5, 3.25]);
        let e = read_weights(&path, 4).unwrap_err().to_string();
        assert!(e.contains("12 bytes") && e.contains("4 parameters"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
