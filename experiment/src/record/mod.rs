//! The file one evaluation stage writes (`eval/...json`) and what is derived from it: the
//! per-world values after trimming and the row of a table.

use std::path::Path;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use sim::Status;

use eval::summarize;

pub mod compact;

use super::plan::write_atomic;
use super::runner::{TracePoint, WorldOutcome};
use compact::{CompactRecord, FORMAT};

/// One controller's evaluation on the test worlds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalRecord {
    /// `ddp`, `constant`, `untrained`, `adp` or `shuffled`.
    pub controller: String,
    /// Planner name.
    pub planner: String,
    /// Action space name (not for DDP).
    pub space: Option<String>,
    /// Speed cap (m/s).
    pub speed: f64,
    /// Training seed index (trained policies and their shuffled twins).
    pub seed_index: Option<usize>,
    /// The constant normalized action (constant controls).
    pub action: Option<Vec<f64>>,
    /// Where the policy came from (network controls).
    pub policy: Option<String>,
    /// Runs per world.
    pub runs: usize,
    /// Runs trimmed from each end per world.
    pub trim: usize,
    /// Base seed of the runs.
    pub seed: u64,
    /// Every run of every world.
    pub per_world: Vec<WorldOutcome>,
    /// Agent steps of run 0 of every world (trained policies only).
    pub trace: Vec<TracePoint>,
    /// What every run's planning cycles did and cost under the compute model (absent from
    /// records written before the model: zero).
    #[serde(default)]
    pub compute: planner::ComputeTally,
    /// The lidar of a sensing-sweep evaluation (absent: the evaluation configuration's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lidar: Option<sim::lidar::LidarConfig>,
}

/// The table values of a set of runs after trimming.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Successful runs (%).
    pub success_pct: f64,
    /// Mean time (s), failures counted as 50 s.
    pub time_s: f64,
    /// Mean BARN score.
    pub score: f64,
    /// Collisions (%).
    pub collision_pct: f64,
    /// Timeouts (%).
    pub timeout_pct: f64,
    /// Mean modelled compute per planning cycle over every run, untrimmed (ms; 0 under the
    /// free model).
    pub compute_ms: f64,
}

impl EvalRecord {
    /// Reads a record of either format ([`compact`]).
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
        Self::parse(&text).with_context(|| format!("{}: not an evaluation record", path.display()))
    }

    /// Parses a record of either format: format 2 (compact) when the object has a `format`
    /// key, format 1 (field by field) otherwise.
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        /// The one key that tells the formats apart (the others are skipped unread).
        #[derive(Deserialize)]
        struct Format {
            format: Option<serde_json::Value>,
        }
        match serde_json::from_str::<Format>(text)?.format {
            None => Ok(serde_json::from_str(text)?),
            Some(f) if f == serde_json::json!(FORMAT) => {
                serde_json::from_str::<CompactRecord>(text)?.expand()
            }
            Some(f) => anyhow::bail!("record format {f} is not one this build reads (1 or {FORMAT})"),
        }
    }

    /// Writes the record atomically, in the compact format 2.
    ///
    /// # Errors
    /// A trace that cannot be stored ([`CompactRecord::of`]) or a failed write.
    pub fn save(&self, path: &Path) -> anyhow::Result<()> {
        let compact =
            CompactRecord::of(self).with_context(|| format!("{}: record not written", path.display()))?;
        write_atomic(path, &serde_json::to_vec(&compact).expect("records serialize"))
    }

    /// Table values over every world, after trimming each world's runs.
    pub fn summary(&self) -> Summary {
        let runs: Vec<_> = self.per_world.iter().map(WorldOutcome::to_world_runs).collect();
        let (success_pct, time_s, score, collision_pct, timeout_pct, _) = summarize(&runs, self.trim);
        Summary {
            success_pct,
            time_s,
            score,
            collision_pct,
            timeout_pct,
            compute_ms: self.compute.ms_per_cycle(),
        }
    }

    /// Per world (in record order): (world, success rate in [0, 1], mean score) after
    /// trimming.
    pub fn per_world_values(&self) -> Vec<(usize, f64, f64)> {
        self.per_world
            .iter()
            .map(|w| {
                let (s, _, score, _, _, _) = summarize(&[w.to_world_runs()], self.trim);
                (w.world, s / 100.0, score)
            })
            .collect()
    }

    /// Success of every run, (world, run) in order, untrimmed: the paired outcomes of
    /// McNemar's test.
    pub fn outcomes(&self) -> Vec<bool> {
        self.per_world
            .iter()
            .flat_map(|w| w.runs.iter().map(|r| r.status == Status::Succeeded))
            .collect()
    }
}

/// A record of one run per world, at 10 s each: `(world, succeeded, score)` per world (for
/// the tests of what reads records).
#[cfg(test)]
pub fn one_run_record(controller: &str, worlds: &[(usize, bool, f64)]) -> EvalRecord {
    use super::runner::WorldOutcome;
    use sim::EpisodeResult;
    EvalRecord {
        controller: controller.into(),
        planner: "dwa".into(),
        space: None,
        speed: 1.5,
        seed_index: None,
        action: None,
        policy: None,
        runs: 1,
        trim: 0,
        seed: 0,
        per_world: worlds
            .iter()
            .map(|&(world, ok, score)| WorldOutcome {
                world,
                runs: vec![EpisodeResult {
                    world,
                    status: if ok { Status::Succeeded } else { Status::Collided },
                    time_s: 10.0,
                    sim_time_s: 10.0,
                    score,
                    distance_m: 0.0,
                }],
            })
            .collect(),
        trace: vec![],
        compute: Default::default(),
        lidar: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::EpisodeResult;

    #[test]
    fn per_world_values_trim_like_the_table() {
        let run = |status, time_s, score| EpisodeResult {
            world: 4,
            status,
            time_s,
            sim_time_s: time_s,
            score,
            distance_m: 0.0,
        };
        let rec = EvalRecord {
            runs: 4,
            trim: 1,
            per_world: vec![WorldOutcome {
                world: 4,
                runs: vec![
                    run(Status::Succeeded, 10.0, 0.4),
                    run(Status::Collided, 3.0, 0.0),
                    run(Status::Succeeded, 8.0, 0.5),
                    run(Status::TimedOut, 100.0, 0.0),
                ],
            }],
            ..one_run_record("ddp", &[])
        };
        // Charged times 10, 50, 8, 50: trim 1 drops 8 and one 50; kept: 10 (success), 50.
        assert_eq!(rec.per_world_values(), vec![(4, 0.5, 0.2)]);
        assert_eq!(rec.outcomes(), vec![true, false, true, false]);
        let s = rec.summary();
        assert_eq!((s.success_pct, s.time_s), (50.0, 30.0));
    }
}
