//! `[greedy]` of a training configuration: how `adp train` monitors its greedy policy.

use serde::{Deserialize, Serialize};

/// `[greedy]` of a training config: how the run's greedy policy is monitored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GreedySection {
    /// Evaluate the newest policy every this many agent steps, and the final one at the end
    /// (default 5000; 0 = never).
    pub every_steps: u64,
    /// Evaluation worlds: a split, range or list (default `val`, held out of the `fit`
    /// training split).
    pub worlds: String,
    /// Runs per world (default 1); run r of world w has the same seed in every evaluation and
    /// for DDP, so the curves are paired.
    pub runs: usize,
}

impl Default for GreedySection {
    fn default() -> Self {
        Self {
            every_steps: 5000,
            worlds: "val".into(),
            runs: 1,
        }
    }
}
