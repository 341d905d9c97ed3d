//! The stuck term of the reward (the 3D RL-DWA paper's `R_stuck`): a robot whose distance to
//! the goal shrank by less than a threshold over the last few agent steps is stuck, and pays
//! for every such step. Pure bookkeeping; the parameters live in [`crate::env::EnvConfig`]
//! (`stuck_window`, `stuck_progress_m`, `stuck_reward`).
//!
//! Without it, the step penalty alone is what a robot that stands still pays, and a policy
//! that drives into obstacles while it learns may find standing still the better bet (the
//! pure-RL arm of `configs/experiments/rl-dwa.toml` did). The term is off by default.

/// The goal distances of an episode's last `window` agent steps, and the progress over them.
///
/// Allocates its window once, when built; [`StuckWindow::push`] never allocates. One per
/// episode, owned by the environment (not shared between threads).
#[derive(Clone, Debug)]
pub struct StuckWindow {
    /// `past[k % window]` = the goal distance after agent step `k` (step 0: the start), for
    /// the last `window` steps.
    past: Vec<f64>,
    /// Agent steps pushed so far.
    steps: usize,
}

impl StuckWindow {
    /// A window of `window` agent steps (at least 1) for an episode that starts `start` metres
    /// from its goal.
    pub fn new(window: usize, start: f64) -> Self {
        Self {
            past: vec![start; window.max(1)],
            steps: 0,
        }
    }

    /// Records the goal distance after the next agent step; returns the progress toward the
    /// goal (m) over the last `window` steps (the distance `window` steps ago minus this one),
    /// or `None` while fewer steps than that have been taken.
    pub fn push(&mut self, distance: f64) -> Option<f64> {
        self.steps += 1;
        let slot = self.steps % self.past.len();
        let progress = (self.steps >= self.past.len()).then(|| self.past[slot] - distance);
        self.past[slot] = distance;
        progress
    }
}

/// The stuck term of a step whose progress over the window is `progress` (`None`: the window
/// is not full yet): `reward` when that progress is below `min_progress`, else 0.
pub fn stuck_term(progress: Option<f64>, min_progress: f64, reward: f64) -> f64 {
    match progress {
        Some(p) if p < min_progress => reward,
        _ => 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_is_measured_over_exactly_the_window() {
        // Start 10 m away; steps bring the robot to 9, 8.5, 8.5, 8.4, 6.
        let mut w = StuckWindow::new(3, 10.0);
        assert_eq!(w.push(9.0), None);
        assert_eq!(w.push(8.5), None);
        // After step 3: the start (10) minus step 3's 8.5.
        assert_eq!(w.push(8.5), Some(1.5));
        // After step 4: step 1's 9 minus 8.4.
        assert!((w.push(8.4).unwrap() - 0.6).abs() < 1e-12);
        // After step 5: step 2's 8.5 minus 6.
        assert_eq!(w.push(6.0), Some(2.5));
    }

    #[test]
    fn a_window_of_one_compares_with_the_previous_step() {
        let mut w = StuckWindow::new(1, 5.0);
        assert_eq!(w.push(4.0), Some(1.0));
        assert_eq!(w.push(4.5), Some(-0.5));
        // A window of 0 behaves as 1.
        let mut w = StuckWindow::new(0, 5.0);
        assert_eq!(w.push(5.0), Some(0.0));
    }

    #[test]
    fn the_term_applies_below_the_threshold_only() {
        assert_eq!(stuck_term(None, 0.5, -5.0), 0.0);
        assert_eq!(stuck_term(Some(0.49), 0.5, -5.0), -5.0);
        assert_eq!(stuck_term(Some(-1.0), 0.5, -5.0), -5.0);
        assert_eq!(stuck_term(Some(0.5), 0.5, -5.0), 0.0);
        assert_eq!(stuck_term(Some(3.0), 0.5, -5.0), 0.0);
    }
}
