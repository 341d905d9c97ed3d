//! The time a training took over every run that worked on it.
//!
//! A training stopped between stages (Ctrl-C, the end of a session, a SLURM time limit that
//! sends a signal first) resumes from its newest checkpoint in a later run. Each run that
//! ends before the training is finished adds its wall-clock time, CPU time and agent steps to
//! `spent.json` in the run directory; the run that finishes it records the sum in the store
//! ([`super::store::StageMeta`]), so `--plan` prices a resumed training like one that ran
//! through. A run killed without a chance to write (SIGKILL, a power cut) leaves no account:
//! the record then says which agent steps its time covers (`timed_units`), and the estimate
//! counts only those.
//!
//! Pure bookkeeping besides [`Spent::load`] and [`Spent::save`]. Thread safety: plain data;
//! one run owns a run directory at a time (the learner holds its lock).

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

use super::plan::write_atomic;

/// The file in a run directory that holds the account of its ended runs.
pub const FILE: &str = "spent.json";

/// What the runs of one training that ended before it finished took, together.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Spent {
    /// Wall-clock seconds.
    pub seconds: f64,
    /// CPU seconds (the experiment process and the processes it waited for); `None` when a
    /// run's were not measured.
    pub cpu_s: Option<f64>,
    /// Agent steps those runs did (each run's steps at its end minus its steps at start).
    pub units: f64,
    /// How many runs it counts.
    pub runs: u32,
}

impl Spent {
    /// This account with one more run: `seconds` on the wall, `cpu_s` of CPU, `units` agent
    /// steps. The CPU time stays measured only while every run's was.
    pub fn plus(self, seconds: f64, cpu_s: Option<f64>, units: f64) -> Spent {
        let cpu_s = match (self.runs, self.cpu_s, cpu_s) {
            (0, _, c) => c,
            (_, Some(a), Some(b)) => Some(a + b),
            _ => None,
        };
        Spent {
            seconds: self.seconds + seconds,
            cpu_s,
            units: self.units + units,
            runs: self.runs + 1,
        }
    }

    /// The account in `run_dir` (empty when there is none: a training's first run).
    pub fn load(run_dir: &Path) -> anyhow::Result<Spent> {
        let file = file(run_dir);
        match std::fs::read_to_string(&file) {
            Ok(text) => serde_json::from_str(&text).with_context(|| {
                format!(
                    "{} is not an account of a training's runs (seconds, cpu_s, units, runs); \
                     delete it to time this training from its next run only",
                    file.display()
                )
            }),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Spent::default()),
            Err(e) => Err(e).with_context(|| format!("cannot read {}", file.display())),
        }
    }

    /// Writes the account into `run_dir`.
    pub fn save(&self, run_dir: &Path) -> anyhow::Result<()> {
        write_atomic(
            &file(run_dir),
            &serde_json::to_vec_pretty(self).expect("accounts serialize"),
        )
    }
}

fn file(run_dir: &Path) -> PathBuf {
    run_dir.join(FILE)
}

/// The agent steps the time of a finished training covers, when fewer than all of them:
/// `Some` when some run's time is missing from `spent` (the steps at the start of the last
/// run, `resumed_from`, exceed what the account's runs did), `None` when the account covers
/// every step.
pub fn timed_units(spent: &Spent, resumed_from: f64, last_run_units: f64) -> Option<f64> {
    (resumed_from > spent.units + 0.5).then_some(spent.units + last_run_units)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_add_up_and_cpu_time_stays_measured_only_while_every_run_was() {
        let one = Spent::default().plus(100.0, Some(150.0), 40_000.0);
        assert_eq!(
            one,
            Spent {
                seconds: 100.0,
                cpu_s: Some(150.0),
                units: 40_000.0,
                runs: 1
            }
        );
        let two = one.plus(50.0, Some(80.0), 20_000.0);
        assert_eq!(
            (two.seconds, two.cpu_s, two.units, two.runs),
            (150.0, Some(230.0), 60_000.0, 2)
        );
        assert_eq!(two.plus(10.0, None, 1.0).cpu_s, None);
        assert_eq!(
            Spent::default()
                .plus(10.0, None, 1.0)
                .plus(1.0, Some(1.0), 1.0)
                .cpu_s,
            None
        );
    }

    #[test]
    fn the_account_round_trips_and_a_missing_one_is_empty() {
        let dir = std::env::temp_dir().join(format!("adp-spent-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert_eq!(Spent::load(&dir).unwrap(), Spent::default());
        let s = Spent::default().plus(12.5, Some(20.0), 3000.0);
        s.save(&dir).unwrap();
        assert_eq!(Spent::load(&dir).unwrap(), s);
        std::fs::write(dir.join(FILE), "{\"seconds\": \"soon\"}").unwrap();
        let err = format!("{:#}", Spent::load(&dir).unwrap_err());
        assert!(err.contains(FILE) && err.contains("delete it"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_run_missing_from_the_account_limits_the_timed_steps() {
        // Ran through in one run.
        assert_eq!(timed_units(&Spent::default(), 0.0, 120_000.0), None);
        // Two accounted runs, then the last from their end.
        let two = Spent::default()
            .plus(1.0, None, 50_000.0)
            .plus(1.0, None, 30_000.0);
        assert_eq!(timed_units(&two, 80_000.0, 40_000.0), None);
        // A run killed without writing its account: 30,000 steps untimed.
        let one = Spent::default().plus(1.0, None, 50_000.0);
        assert_eq!(timed_units(&one, 80_000.0, 40_000.0), Some(90_000.0));
        // Resumed from a checkpoint no accounted run made (a record from before accounts).
        assert_eq!(timed_units(&Spent::default(), 84_646.0, 35_357.0), Some(35_357.0));
    }
}
