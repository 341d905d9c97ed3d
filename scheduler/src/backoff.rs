//! Restart back-off for crashed children: pure bookkeeping, no processes.

use std::time::Duration;

use serde::{Deserialize, Serialize};

/// Exponential restart back-off: the `k`-th consecutive crash (0-based) waits
/// `min(base * factor^k, max)`; a child that ran longer than `reset_after` before crashing
/// starts again from `k = 0`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BackoffPolicy {
    /// The first delay.
    pub base: Duration,
    /// Growth per consecutive crash; finite and at least 1.
    pub factor: f64,
    /// The largest delay.
    pub max: Duration,
    /// A run longer than this resets the back-off.
    pub reset_after: Duration,
}

impl Default for BackoffPolicy {
    /// 0.5 s base, factor 2, 30 s cap, reset after 60 s of running.
    fn default() -> Self {
        Self {
            base: Duration::from_millis(500),
            factor: 2.0,
            max: Duration::from_secs(30),
            reset_after: Duration::from_secs(60),
        }
    }
}

impl BackoffPolicy {
    /// Whether the policy is usable: `factor` finite and at least 1, `base <= max`.
    pub fn is_valid(&self) -> bool {
        self.factor.is_finite() && self.factor >= 1.0 && self.base <= self.max
    }
}

/// The back-off state of one child. Plain data (`Send`, `Sync`).
#[derive(Debug, Clone, PartialEq)]
pub struct Backoff {
    policy: BackoffPolicy,
    consecutive: u32,
}

impl Backoff {
    /// A fresh state (no crash yet) under `policy`, which should satisfy
    /// [`BackoffPolicy::is_valid`]; delays stay within `[0, max]` even if it does not.
    pub fn new(policy: BackoffPolicy) -> Self {
        Self {
            policy,
            consecutive: 0,
        }
    }

    /// Records a crash after the child ran for `ran_for` and returns how long to wait before
    /// restarting it.
    pub fn on_crash(&mut self, ran_for: Duration) -> Duration {
        if ran_for > self.policy.reset_after {
            self.consecutive = 0;
        }
        let exponent = i32::try_from(self.consecutive).unwrap_or(i32::MAX);
        let seconds = self.policy.base.as_secs_f64() * self.policy.factor.powi(exponent);
        self.consecutive = self.consecutive.saturating_add(1);
        if (0.0..self.policy.max.as_secs_f64()).contains(&seconds) {
            Duration::from_secs_f64(seconds)
        } else {
            self.policy.max
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(ms: u64) -> Duration {
        Duration::from_millis(ms)
    }

    #[test]
    fn delays_double_up_to_the_cap() {
        let mut backoff = Backoff::new(BackoffPolicy::default());
        let delays: Vec<Duration> = (0..9).map(|_| backoff.on_crash(ms(100))).collect();
        let expected = [500, 1_000, 2_000, 4_000, 8_000, 16_000, 30_000, 30_000, 30_000];
        assert_eq!(delays, expected.map(ms));
    }

    #[test]
    fn a_long_run_resets_the_back_off() {
        let mut backoff = Backoff::new(BackoffPolicy::default());
        backoff.on_crash(ms(10));
        backoff.on_crash(ms(10));
        assert_eq!(
            backoff.on_crash(ms(60_000)),
            ms(2_000),
            "exactly reset_after does not reset"
        );
        assert_eq!(backoff.on_crash(ms(60_001)), ms(500));
        assert_eq!(backoff.on_crash(ms(10)), ms(1_000));
    }

    #[test]
    fn many_crashes_do_not_overflow() {
        let mut backoff = Backoff::new(BackoffPolicy {
            factor: 10.0,
            ..BackoffPolicy::default()
        });
        let last = (0..10_000).map(|_| backoff.on_crash(ms(0))).last();
        assert_eq!(last, Some(ms(30_000)));
    }

    #[test]
    fn validity() {
        assert!(BackoffPolicy::default().is_valid());
        assert!(!BackoffPolicy {
            factor: 0.5,
            ..BackoffPolicy::default()
        }
        .is_valid());
        assert!(!BackoffPolicy {
            factor: f64::NAN,
            ..BackoffPolicy::default()
        }
        .is_valid());
        assert!(!BackoffPolicy {
            base: ms(40_000),
            ..BackoffPolicy::default()
        }
        .is_valid());
    }
}
