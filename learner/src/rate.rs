//! A samples-per-insert rate limiter (as in DeepMind Reverb), counted in gradient updates per
//! inserted agent step.
//!
//! After `warmup` inserts, the target number of updates is `ratio * (inserts - warmup)`. The
//! learner may run an update while `updates + 1 <= target + tolerance`, and the actors may
//! insert while the learner lags by at most `tolerance` updates after that insert. So however
//! fast or slow the actor fleet is, `|updates - target| <= tolerance` holds at every point the
//! caller honours the limiter: the ratio is a property of the algorithm, not of the hardware.

use serde::{Deserialize, Serialize};

use crate::config::Td3Config;

/// Counts inserts and updates and says which of the two may proceed.
///
/// Pure bookkeeping: it never blocks or sleeps; the caller asks ([`RateLimiter::updates_allowed`],
/// [`RateLimiter::inserts_allowed`]), acts, then records ([`RateLimiter::record_inserts`],
/// [`RateLimiter::record_updates`]). Plain data (`Send + Sync`); wrap it in a mutex to share it
/// between the insert and update threads, and checkpoint it with serde.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RateLimiter {
    warmup: u64,
    ratio: f64,
    tolerance: f64,
    inserts: u64,
    updates: u64,
}

impl RateLimiter {
    /// A limiter with `warmup_steps`, `updates_per_insert` and `rate_tolerance` of a (valid)
    /// config and zero counts.
    pub fn new(config: &Td3Config) -> Self {
        Self {
            warmup: config.warmup_steps,
            ratio: config.updates_per_insert,
            tolerance: config.rate_tolerance,
            inserts: 0,
            updates: 0,
        }
    }

    /// Agent steps inserted so far.
    pub fn inserts(&self) -> u64 {
        self.inserts
    }

    /// Gradient updates run so far.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Whether warm-up is over (training may start).
    pub fn warmed_up(&self) -> bool {
        self.inserts >= self.warmup
    }

    /// Updates the algorithm calls for after the inserts so far: `ratio * (inserts - warmup)`,
    /// zero during warm-up.
    pub fn target_updates(&self) -> f64 {
        self.ratio * self.inserts.saturating_sub(self.warmup) as f64
    }

    /// Observed updates per post-warm-up insert (`None` before the first such insert).
    pub fn observed_ratio(&self) -> Option<f64> {
        let n = self.inserts.saturating_sub(self.warmup);
        (n > 0).then(|| self.updates as f64 / n as f64)
    }

    /// How many updates may run now without exceeding `target + tolerance` (0 in warm-up).
    pub fn updates_allowed(&self) -> u64 {
        if !self.warmed_up() {
            return 0;
        }
        let room = self.target_updates() + self.tolerance - self.updates as f64;
        room.max(0.0).floor() as u64
    }

    /// How many agent steps may be inserted now without the learner lagging more than
    /// `tolerance` updates behind the target (`u64::MAX` when unbounded, i.e. while the
    /// remaining warm-up alone is larger; warm-up inserts are always allowed).
    pub fn inserts_allowed(&self) -> u64 {
        // Largest i with ratio * (inserts + i - warmup) - updates <= tolerance.
        let max_post_warmup = ((self.updates as f64 + self.tolerance) / self.ratio).floor();
        if max_post_warmup >= (u64::MAX - self.warmup) as f64 {
            return u64::MAX;
        }
        (self.warmup + max_post_warmup as u64).saturating_sub(self.inserts)
    }

    /// Record `n` inserted agent steps (also when they exceeded [`Self::inserts_allowed`]:
    /// the data is kept, and updates catch up).
    pub fn record_inserts(&mut self, n: u64) {
        self.inserts += n;
    }

    /// Record `n` completed gradient updates.
    pub fn record_updates(&mut self, n: u64) {
        self.updates += n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limiter(warmup: u64, ratio: f64, tolerance: f64) -> RateLimiter {
        RateLimiter::new(&Td3Config {
            warmup_steps: warmup,
            updates_per_insert: ratio,
            rate_tolerance: tolerance,
            ..Td3Config::default()
        })
    }

    #[test]
    fn no_updates_during_warmup_then_tolerance_worth() {
        let mut r = limiter(1024, 1.0, 16.0);
        r.record_inserts(1023);
        assert_eq!((r.updates_allowed(), r.warmed_up()), (0, false));
        r.record_inserts(1);
        assert_eq!((r.updates_allowed(), r.warmed_up()), (16, true));
        r.record_updates(16);
        assert_eq!(r.updates_allowed(), 0);
        r.record_inserts(5);
        assert_eq!(r.updates_allowed(), 5);
    }

    #[test]
    fn inserts_block_when_learner_lags_by_the_tolerance() {
        let mut r = limiter(100, 1.0, 10.0);
        assert_eq!(r.inserts_allowed(), 110);
        r.record_inserts(110);
        assert_eq!(r.inserts_allowed(), 0);
        r.record_updates(3);
        assert_eq!(r.inserts_allowed(), 3);
    }

    #[test]
    fn fractional_ratio() {
        let mut r = limiter(0, 0.25, 1.0);
        r.record_inserts(8);
        assert_eq!(r.target_updates(), 2.0);
        assert_eq!(r.updates_allowed(), 3);
        r.record_updates(3);
        assert_eq!(r.inserts_allowed(), 8);
        assert_eq!(r.observed_ratio(), Some(3.0 / 8.0));
    }

    /// Simulated fleets of any speed: the ratio stays within tolerance of the target.
    #[test]
    fn ratio_holds_for_fast_and_slow_fleets() {
        for (ratio, inserts_per_tick, updates_per_tick) in [
            (1.0, 50, 3),
            (1.0, 1, 40),
            (2.0, 7, 7),
            (0.5, 13, 2),
            (1.0, 200, 200),
        ] {
            let tol = 64.0;
            let mut r = limiter(1024, ratio, tol);
            for _ in 0..5_000 {
                let n = r.inserts_allowed().min(inserts_per_tick);
                r.record_inserts(n);
                let u = r.updates_allowed().min(updates_per_tick);
                r.record_updates(u);
                if r.warmed_up() {
                    let dev = r.updates as f64 - r.target_updates();
                    assert!(dev.abs() <= tol + ratio, "ratio {ratio}: deviation {dev}");
                }
            }
            let observed = r.observed_ratio().unwrap();
            assert!(
                (observed - ratio).abs() < 0.05 * ratio,
                "ratio {ratio}: observed {observed}"
            );
        }
    }

    #[test]
    fn serde_round_trip() {
        let mut r = limiter(3, 1.5, 4.0);
        r.record_inserts(10);
        r.record_updates(7);
        let back: RateLimiter = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back, r);
    }
}
