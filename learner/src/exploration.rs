//! The exploration-noise schedule: sigma decays linearly over a budget of agent steps.

use serde::{Deserialize, Serialize};

use crate::config::Td3Config;

/// `sigma(step) = start + (end - start) * min(step / steps, 1)`, in normalized action units.
///
/// `step` counts agent steps inserted into the replay buffer (the run's global step). The
/// learner evaluates it when it publishes a policy version and ships the value with that
/// version, so every actor using the version explores with the same sigma. Plain data.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExplorationSchedule {
    /// Sigma at step 0.
    pub start: f64,
    /// Sigma from `steps` on.
    pub end: f64,
    /// Length of the decay in agent steps (> 0).
    pub steps: u64,
}

impl ExplorationSchedule {
    /// The schedule of a (valid) config in a run of `budget` agent steps:
    /// `exploration_start -> exploration_end` over `exploration_steps`, or over the budget when
    /// that is 0.
    pub fn new(config: &Td3Config, budget: u64) -> Self {
        let steps = match config.exploration_steps {
            0 => budget,
            n => n,
        };
        Self {
            start: config.exploration_start,
            end: config.exploration_end,
            steps: steps.max(1),
        }
    }

    /// Sigma after `step` agent steps.
    pub fn sigma(&self, step: u64) -> f64 {
        let frac = (step as f64 / self.steps as f64).min(1.0);
        self.start + (self.end - self.start) * frac
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decays_linearly_from_start_to_end_then_stays() {
        let s = ExplorationSchedule::new(
            &Td3Config {
                exploration_steps: 1000,
                ..Td3Config::default()
            },
            40_000,
        );
        let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        close(s.sigma(0), 0.2);
        close(s.sigma(250), 0.1625);
        close(s.sigma(500), 0.125);
        close(s.sigma(1000), 0.05);
        close(s.sigma(1_000_000), 0.05);
        assert!((0..1000).all(|t| s.sigma(t + 1) < s.sigma(t)));
    }

    #[test]
    fn zero_steps_decay_over_the_run_budget() {
        let s = ExplorationSchedule::new(&Td3Config::default(), 40_000);
        assert_eq!(s.steps, 40_000);
        assert!((s.sigma(20_000) - 0.125).abs() < 1e-12);
        assert!((s.sigma(40_000) - 0.05).abs() < 1e-12);
        assert_eq!(ExplorationSchedule::new(&Td3Config::default(), 0).steps, 1);
    }
}
