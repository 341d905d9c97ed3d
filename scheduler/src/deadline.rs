//! How long a cycle and a lease may take: deadlines derived from measured episode times.
//! Pure arithmetic over a window of measurements; the [`Registry`](crate::Registry) applies it.
//!
//! The registry measures every finished lease (from its assignment to its finish) and keeps
//! the per-episode time of the newest [`EPISODE_TIMES_KEPT`] ([`EpisodeTimes`]). From their
//! median `m` and a [`DeadlineRule`] (`multiple` k, `floor_ms` f):
//!
//! - the **span** of an assignment of `e` episodes is `max(f, k x m x e)`: a cycle ends at the
//!   latest one span after its first assignment, and a late actor's lease one span after it was
//!   assigned ([`DeadlineRule::span_ms`]);
//! - the **stall bound** of a lease is `max(f, k x m)`: a lease without progress (no step
//!   stored, no report accepted) for that long ends early ([`DeadlineRule::stall_ms`]).
//!
//! Without a measurement (nothing finished yet in this learner process) neither applies, and
//! with `multiple = 0` never. If leases end at a deadline and no lease finished during their
//! cycle (or, for a late actor's lease, since it was assigned), every actor may have slowed
//! down together (longer episodes as the policy improves): the window is replaced by the
//! span's episode time ([`EpisodeTimes::stretch`]), so the next span is k times longer, until
//! a lease finishes again. A straggler cannot stretch the spans while others finish leases.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

/// Episode times kept for the median (the newest).
pub const EPISODE_TIMES_KEPT: usize = 64;

/// The deadline settings: a multiple of the median episode time, with a floor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct DeadlineRule {
    /// k: a span is k times the median time of the assignment's episodes; 0 turns cycle and
    /// lease deadlines off (the cycle then waits for every lease, as before).
    pub multiple: u32,
    /// No span or stall bound is shorter than this (ms).
    pub floor_ms: u64,
}

impl Default for DeadlineRule {
    /// k = 4, floor 10 s.
    fn default() -> Self {
        Self {
            multiple: 4,
            floor_ms: 10_000,
        }
    }
}

impl DeadlineRule {
    /// No deadlines at all.
    pub const OFF: Self = Self {
        multiple: 0,
        floor_ms: 0,
    };

    /// The span of an assignment of `episodes` episodes, `max(floor, k x median x episodes)`;
    /// `None` without a median or with deadlines off.
    pub fn span_ms(&self, median_episode_ms: Option<u64>, episodes: u32) -> Option<u64> {
        let median = median_episode_ms.filter(|_| self.multiple > 0)?;
        let span = median
            .saturating_mul(u64::from(self.multiple))
            .saturating_mul(u64::from(episodes.max(1)));
        Some(span.max(self.floor_ms))
    }

    /// How long a lease may go without progress, `max(floor, k x median)`; `None` without a
    /// median or with deadlines off.
    pub fn stall_ms(&self, median_episode_ms: Option<u64>) -> Option<u64> {
        self.span_ms(median_episode_ms, 1)
    }
}

/// The per-episode times of the newest finished leases (see the module documentation).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct EpisodeTimes {
    /// Oldest first, at most [`EPISODE_TIMES_KEPT`].
    times: VecDeque<u64>,
}

impl EpisodeTimes {
    /// Records a lease of `episodes` episodes that finished `lease_ms` after its assignment.
    pub fn record(&mut self, lease_ms: u64, episodes: u32) {
        self.times.push_back(lease_ms / u64::from(episodes.max(1)));
        if self.times.len() > EPISODE_TIMES_KEPT {
            self.times.pop_front();
        }
    }

    /// The median episode time (the lower middle of an even count); `None` before the first
    /// measurement.
    pub fn median(&self) -> Option<u64> {
        let mut sorted: Vec<u64> = self.times.iter().copied().collect();
        sorted.sort_unstable();
        sorted.get(sorted.len().saturating_sub(1) / 2).copied()
    }

    /// A whole span of `episodes` episodes passed under `rule` without a finished lease:
    /// the measurements are replaced by the span's episode time, so the median becomes k
    /// times the old one (and the next span k times longer). Does nothing without a median
    /// or with deadlines off.
    pub fn stretch(&mut self, rule: &DeadlineRule, episodes: u32) {
        if let Some(span) = rule.span_ms(self.median(), episodes) {
            self.times.clear();
            self.record(span, episodes);
        }
    }

    /// How many measurements are kept.
    pub fn len(&self) -> usize {
        self.times.len()
    }

    /// Whether nothing was measured yet.
    pub fn is_empty(&self) -> bool {
        self.times.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RULE: DeadlineRule = DeadlineRule {
        multiple: 3,
        floor_ms: 500,
    };

    #[test]
    fn spans_are_a_multiple_of_the_median_with_a_floor() {
        assert_eq!(RULE.span_ms(None, 2), None, "nothing measured: no deadline");
        assert_eq!(RULE.span_ms(Some(1_000), 2), Some(6_000));
        assert_eq!(RULE.span_ms(Some(10), 2), Some(500), "the floor");
        assert_eq!(RULE.stall_ms(Some(1_000)), Some(3_000));
        assert_eq!(RULE.stall_ms(Some(100)), Some(500));
        assert_eq!(DeadlineRule::OFF.span_ms(Some(1_000), 2), None);
        assert_eq!(DeadlineRule::OFF.stall_ms(Some(1_000)), None);
        assert_eq!(RULE.span_ms(Some(u64::MAX), 2), Some(u64::MAX), "saturates");
        assert_eq!(
            RULE.span_ms(Some(1_000), 0),
            Some(3_000),
            "zero episodes count as one"
        );
    }

    #[test]
    fn the_median_is_over_the_newest_episode_times() {
        let mut times = EpisodeTimes::default();
        assert_eq!(times.median(), None);
        times.record(2_000, 2);
        assert_eq!(times.median(), Some(1_000));
        times.record(100, 2);
        times.record(300, 2);
        assert_eq!(times.median(), Some(150), "50, 150, 1000: the middle one");
        times.record(50, 2);
        assert_eq!(times.median(), Some(50), "25, 50, 150, 1000: the lower middle");
        // A straggler's few slow leases do not move the median of many fast ones.
        let mut times = EpisodeTimes::default();
        for _ in 0..40 {
            times.record(200, 2);
        }
        for _ in 0..10 {
            times.record(200_000, 2);
        }
        assert_eq!(times.median(), Some(100));
        // Only the newest are kept.
        for _ in 0..EPISODE_TIMES_KEPT {
            times.record(600, 2);
        }
        assert_eq!((times.len(), times.median()), (EPISODE_TIMES_KEPT, Some(300)));
    }

    #[test]
    fn a_span_without_a_finished_lease_stretches_the_next_one() {
        let mut times = EpisodeTimes::default();
        times.stretch(&RULE, 2);
        assert!(times.is_empty(), "nothing to stretch");
        for _ in 0..10 {
            times.record(1_000, 2);
        }
        assert_eq!(RULE.span_ms(times.median(), 2), Some(3_000));
        times.stretch(&RULE, 2);
        assert_eq!(RULE.span_ms(times.median(), 2), Some(9_000));
        times.stretch(&RULE, 2);
        assert_eq!(RULE.span_ms(times.median(), 2), Some(27_000));
        assert_eq!(times.len(), 1);
        // The floor stretches too: a median below it becomes the floor's share.
        let mut fast = EpisodeTimes::default();
        fast.record(2, 2);
        fast.stretch(&RULE, 2);
        assert_eq!(fast.median(), Some(250));
        assert_eq!(RULE.span_ms(fast.median(), 2), Some(1_500));
        let mut off = EpisodeTimes::default();
        off.record(10, 1);
        off.stretch(&DeadlineRule::OFF, 2);
        assert_eq!(off.median(), Some(10));
    }
}
