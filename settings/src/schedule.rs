//! Fidelity schedules: the time grid a planner rolls out over, and how many footprint
//! boundary points it collision-checks after each step.
//!
//! A schedule is plain data, so fixed strategies (vanilla, DDP) and a learned policy (ADP)
//! produce the same type and any planner can consume it.

use serde::{Deserialize, Serialize};

/// Number of footprint boundary points of a full-fidelity collision check.
pub const DEFAULT_BOUNDARY_POINTS: usize = 20;

/// A rollout time grid: step `i` lasts `dts[i]` seconds and the state after it is checked
/// with `checks[i]` boundary points (the robot centre is always checked).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Schedule {
    dts: Vec<f64>,
    checks: Vec<u16>,
    boundary_points: usize,
}

/// A schedule that cannot be used.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ScheduleError {
    /// A parameter out of its domain.
    #[error("schedule parameter {name} = {value} is invalid: {why}")]
    Param {
        /// Parameter name.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What it must be.
        why: &'static str,
    },
}

fn check(name: &'static str, value: f64, ok: bool, why: &'static str) -> Result<(), ScheduleError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(ScheduleError::Param { name, value, why })
    }
}

impl Schedule {
    /// The vanilla planners' grid: 20 uniform steps of 0.05 s (1 s horizon), every boundary
    /// point checked at every step.
    pub fn vanilla() -> Self {
        Self::uniform(0.05, 20, DEFAULT_BOUNDARY_POINTS).expect("valid constants")
    }

    /// `steps` uniform steps of `dt` seconds, all `boundary_points` checked at each.
    pub fn uniform(dt: f64, steps: usize, boundary_points: usize) -> Result<Self, ScheduleError> {
        check("dt", dt, dt > 0.0, "must be > 0")?;
        check("steps", steps as f64, steps >= 1, "must be >= 1")?;
        Ok(Self {
            dts: vec![dt; steps],
            checks: vec![boundary_points as u16; steps],
            boundary_points,
        })
    }

    /// The DDP paper's default: T = 2 s, N = 20, p = 1.7.
    pub fn ddp_default() -> Self {
        Self::ddp(1.7, 2.0, 20, DEFAULT_BOUNDARY_POINTS).expect("valid constants")
    }

    /// Decremental dynamics planning: t_i = T (i/N)^p for i = 0..N, so steps lengthen along
    /// the rollout when p > 1, and the state after step t is checked with
    /// N_t = round(n (1 - (t/N)^p)) boundary points (none at the horizon; the centre always).
    pub fn ddp(p: f64, total_time: f64, steps: usize, n: usize) -> Result<Self, ScheduleError> {
        check("p", p, p > 0.0, "must be > 0")?;
        Self::decremental(p, total_time, steps, 0.0, n)
    }

    /// The ADP decremental family: t_i = alpha (i/N) T + (1 - alpha) (i/N)^p T, with the
    /// check density decaying as in DDP. `alpha` = 0 is DDP; `alpha` = 1 is uniform.
    pub fn decremental(
        p: f64,
        total_time: f64,
        steps: usize,
        alpha: f64,
        n: usize,
    ) -> Result<Self, ScheduleError> {
        check("p", p, p > 0.0, "must be > 0")?;
        check("T", total_time, total_time > 0.0, "must be > 0")?;
        check("N", steps as f64, steps >= 1, "must be >= 1")?;
        check("alpha", alpha, (0.0..=1.0).contains(&alpha), "must be in [0, 1]")?;
        let nf = steps as f64;
        let t = |i: usize| {
            let f = i as f64 / nf;
            alpha * f * total_time + (1.0 - alpha) * f.powf(p) * total_time
        };
        let dts = (1..=steps).map(|i| t(i) - t(i - 1)).collect();
        let checks = (1..=steps)
            .map(|i| (n as f64 * (1.0 - (i as f64 / nf).powf(p))).round() as u16)
            .collect();
        Ok(Self {
            dts,
            checks,
            boundary_points: n,
        })
    }

    /// A schedule from explicit step lengths and per-step check counts (each count is capped
    /// at `n`).
    pub fn from_parts(dts: Vec<f64>, checks: Vec<u16>, n: usize) -> Result<Self, ScheduleError> {
        check(
            "steps",
            dts.len() as f64,
            !dts.is_empty() && dts.len() == checks.len(),
            "need one check count per step",
        )?;
        for &d in &dts {
            check("dt", d, d > 0.0, "must be > 0")?;
        }
        let checks = checks.into_iter().map(|c| c.min(n as u16)).collect();
        Ok(Self {
            dts,
            checks,
            boundary_points: n,
        })
    }

    /// The same steps and check counts in reverse order.
    pub fn reversed(mut self) -> Self {
        self.dts.reverse();
        self.checks.reverse();
        self
    }

    /// Step lengths (s).
    pub fn dts(&self) -> &[f64] {
        &self.dts
    }

    /// Boundary points checked after each step.
    pub fn checks(&self) -> &[u16] {
        &self.checks
    }

    /// Boundary points of a full check (n).
    pub fn boundary_points(&self) -> usize {
        self.boundary_points
    }

    /// Number of steps N.
    pub fn len(&self) -> usize {
        self.dts.len()
    }

    /// True for a schedule without steps (never produced by the constructors).
    pub fn is_empty(&self) -> bool {
        self.dts.is_empty()
    }

    /// Rollout horizon: the sum of the steps (s).
    pub fn horizon(&self) -> f64 {
        self.dts.iter().sum()
    }

    /// Collision-check points evaluated by one rollout that reaches the horizon: the centre
    /// plus the boundary points, at every step.
    pub fn points_per_rollout(&self) -> usize {
        self.checks.iter().map(|&c| 1 + c as usize).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vanilla_is_uniform_one_second() {
        let s = Schedule::vanilla();
        assert_eq!(s.len(), 20);
        assert!(s.dts().iter().all(|&d| (d - 0.05).abs() < 1e-15));
        assert!((s.horizon() - 1.0).abs() < 1e-12);
        assert!(s.checks().iter().all(|&c| c as usize == DEFAULT_BOUNDARY_POINTS));
    }

    #[test]
    fn ddp_matches_the_authors_published_intervals() {
        // The p = 1.7, T = 2, N = 20 intervals hard-coded in the authors' DDP planner.
        let published = [
            0.0123, 0.0276, 0.0396, 0.0501, 0.0598, 0.0688, 0.0774, 0.0855, 0.0934, 0.1009, 0.1083, 0.1154,
            0.1223, 0.1291, 0.1357, 0.1422, 0.1486, 0.1548, 0.1610, 0.1670,
        ];
        let s = Schedule::ddp_default();
        for (a, b) in s.dts().iter().zip(published) {
            assert!((a - b).abs() < 6e-5, "{a} vs {b}");
        }
        assert!((s.horizon() - 2.0).abs() < 1e-12, "the steps sum to T");
        // Decreasing fidelity: every step at least as long as the one before.
        assert!(s.dts().windows(2).all(|w| w[1] > w[0]));
    }

    #[test]
    fn ddp_check_counts_follow_n_t() {
        let s = Schedule::ddp(1.7, 2.0, 20, 16).unwrap();
        for (i, &c) in s.checks().iter().enumerate() {
            let t = (i + 1) as f64 / 20.0;
            assert_eq!(c, (16.0 * (1.0 - t.powf(1.7))).round() as u16);
        }
        assert_eq!(s.checks()[0], 16, "first step: (1/20)^1.7 is tiny");
        assert_eq!(*s.checks().last().unwrap(), 0, "horizon: centre only");
        assert!(s.checks().windows(2).all(|w| w[1] <= w[0]));
        // DDP checks fewer points per rollout than vanilla at the same N.
        assert!(s.points_per_rollout() < Schedule::vanilla().points_per_rollout());
    }

    #[test]
    fn blend_and_errors() {
        let uniform = Schedule::decremental(1.7, 2.0, 10, 1.0, 16).unwrap();
        assert!(uniform.dts().iter().all(|&d| (d - 0.2).abs() < 1e-12));
        let blend = Schedule::decremental(1.5, 1.8, 16, 0.3, 16).unwrap();
        assert!((blend.horizon() - 1.8).abs() < 1e-12);
        assert!(matches!(
            Schedule::ddp(1.7, f64::NAN, 20, 16),
            Err(ScheduleError::Param { name: "T", .. })
        ));
        assert!(Schedule::ddp(1.7, 2.0, 0, 16).is_err());
        assert!(Schedule::uniform(-0.1, 5, 4).is_err());
    }
}
