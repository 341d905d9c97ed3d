//! Fair, reproducible dealing of training worlds to assignments.
//!
//! Every world has a *share*: the number of assignments dealt for it that have not been lost,
//! i.e. `completed + in_flight + pending`, where `pending` counts assignments whose lease
//! expired ([`Dealer::release`]) and that wait to be dealt again. [`Dealer::deal`] serves the
//! pending queue first (oldest release first) and otherwise deals a world of the smallest share,
//! so at all times `max(share) - min(share) <= 1`; once the pending queue is empty (the normal
//! state between lease expiries) the share is exactly `completed + in_flight`.
//!
//! Ties between worlds of the smallest share are broken by a per-pass order: pass `p` is the
//! phase in which the smallest share is `p`, and its order is a shuffle of the worlds by a
//! [`Pcg64Mcg`] seeded from `(seed, p)`. So the order differs from pass to pass, and the whole
//! sequence is a function of the seed and the sequence of calls.
//!
//! A *fresh* dealer ([`Dealer::fresh`], [`WorldPool::Fresh`]) has no list: it deals the ids
//! `first, first + 1, ...` in order, each once (a released assignment is still dealt again
//! before a new world), so every assignment meets a world no earlier assignment met. Its worlds
//! are the ones dealt so far, every share is 1, and the seed plays no part.

use std::collections::VecDeque;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use crate::seed::splitmix64;

/// Why a [`Dealer`] could not be built or could not apply an operation.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DealerError {
    /// The list of worlds is empty.
    #[error("the dealer needs at least one world, got none")]
    NoWorlds,
    /// A world id appears more than once in the list of worlds.
    #[error("world {0} is listed more than once")]
    DuplicateWorld(usize),
    /// The world id is not one of the dealer's worlds.
    #[error("world {0} is not one of the dealer's worlds")]
    UnknownWorld(usize),
    /// [`Dealer::complete`] or [`Dealer::release`] for a world without an in-flight assignment.
    #[error("world {0} has no in-flight assignment to complete or release")]
    NothingInFlight(usize),
    /// A deserialized dealer state is inconsistent (wrong lengths, unknown pending world).
    #[error("inconsistent dealer state: {0}")]
    InconsistentState(String),
}

/// The training worlds a [`Dealer`] deals from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum WorldPool {
    /// These worlds (non-empty, no duplicates), dealt fairly.
    Listed(Vec<usize>),
    /// An unbounded run of ids from `first` on, a new one for every assignment.
    Fresh {
        /// The first id dealt.
        first: usize,
    },
}

/// Per-world assignment counts, as reported by [`Dealer::counts`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct WorldCount {
    /// The world id.
    pub world: usize,
    /// Assignments of this world that finished.
    pub completed: u64,
    /// Assignments of this world that are dealt and neither completed nor released.
    pub in_flight: u64,
    /// Released assignments of this world waiting to be dealt again.
    pub pending: u64,
}

/// Deals training worlds fairly (see the module documentation).
///
/// Plain data without interior mutability: `Send` and `Sync`, mutated through `&mut self`.
/// Serializes as its counts and seed (the per-pass order is recomputed on deserialization,
/// which validates the state).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "DealerState", into = "DealerState")]
pub struct Dealer {
    worlds: Vec<usize>,
    seed: u64,
    completed: Vec<u64>,
    in_flight: Vec<u64>,
    /// Indices (into `worlds`) of released assignments, oldest first.
    pending: VecDeque<usize>,
    /// `completed + in_flight + pending` per world index.
    shares: Vec<u64>,
    /// The current pass: the smallest share.
    pass: u64,
    /// World indices in tie-break order for the current pass (empty when fresh).
    order: Vec<usize>,
    /// The first id of a fresh dealer's unbounded run (`None`: the listed worlds only).
    fresh: Option<usize>,
}

/// The serialized form of a [`Dealer`].
#[derive(Debug, Clone, Serialize, Deserialize)]
struct DealerState {
    worlds: Vec<usize>,
    seed: u64,
    completed: Vec<u64>,
    in_flight: Vec<u64>,
    pending: Vec<usize>,
    /// A fresh dealer's first id (absent in the state of a listed dealer).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fresh: Option<usize>,
}

impl Dealer {
    /// A dealer over `pool` with tie-break seed `seed` ([`Dealer::new`] or [`Dealer::fresh`]).
    pub fn of_pool(pool: WorldPool, seed: u64) -> Result<Self, DealerError> {
        match pool {
            WorldPool::Listed(worlds) => Self::new(worlds, seed),
            WorldPool::Fresh { first } => Ok(Self::fresh(first, seed)),
        }
    }

    /// A fresh dealer: ids `first, first + 1, ...`, each dealt once (see the module
    /// documentation).
    pub fn fresh(first: usize, seed: u64) -> Self {
        Self::from_state(DealerState {
            worlds: Vec::new(),
            seed,
            completed: Vec::new(),
            in_flight: Vec::new(),
            pending: Vec::new(),
            fresh: Some(first),
        })
        .expect("an empty fresh dealer is consistent")
    }

    /// A dealer over `worlds` (non-empty, no duplicates) with tie-break seed `seed`; all
    /// counts start at zero.
    pub fn new(worlds: Vec<usize>, seed: u64) -> Result<Self, DealerError> {
        let n = worlds.len();
        Self::from_state(DealerState {
            worlds,
            seed,
            completed: vec![0; n],
            in_flight: vec![0; n],
            pending: Vec::new(),
            fresh: None,
        })
    }

    fn from_state(state: DealerState) -> Result<Self, DealerError> {
        let DealerState {
            worlds,
            seed,
            completed,
            in_flight,
            pending,
            fresh,
        } = state;
        if worlds.is_empty() && fresh.is_none() {
            return Err(DealerError::NoWorlds);
        }
        if let Some(first) = fresh {
            if let Some((i, w)) = worlds
                .iter()
                .enumerate()
                .find(|&(i, &w)| w != first.wrapping_add(i))
            {
                return Err(DealerError::InconsistentState(format!(
                    "a fresh dealer from {first} lists world {w} at position {i}"
                )));
            }
        }
        let mut sorted = worlds.clone();
        sorted.sort_unstable();
        if let Some(pair) = sorted.windows(2).find(|pair| pair[0] == pair[1]) {
            return Err(DealerError::DuplicateWorld(pair[0]));
        }
        if completed.len() != worlds.len() || in_flight.len() != worlds.len() {
            return Err(DealerError::InconsistentState(format!(
                "{} worlds but {} completed and {} in-flight counts",
                worlds.len(),
                completed.len(),
                in_flight.len()
            )));
        }
        let mut shares: Vec<u64> = completed.iter().zip(&in_flight).map(|(c, f)| c + f).collect();
        let mut queue = VecDeque::with_capacity(pending.len());
        for world in pending {
            let index = worlds
                .iter()
                .position(|&w| w == world)
                .ok_or_else(|| DealerError::InconsistentState(format!("pending world {world} is unknown")))?;
            shares[index] += 1;
            queue.push_back(index);
        }
        let min = shares.iter().copied().min().unwrap_or(0);
        let max = shares.iter().copied().max().unwrap_or(0);
        if max - min > 1 {
            return Err(DealerError::InconsistentState(format!(
                "world shares range from {min} to {max}, more than one apart"
            )));
        }
        let mut dealer = Self {
            worlds,
            seed,
            completed,
            in_flight,
            pending: queue,
            shares,
            pass: min,
            order: Vec::new(),
            fresh,
        };
        if fresh.is_none() {
            dealer.order = dealer.pass_order(min);
        }
        Ok(dealer)
    }

    /// The tie-break order of pass `pass`.
    fn pass_order(&self, pass: u64) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.worlds.len()).collect();
        order.shuffle(&mut Pcg64Mcg::seed_from_u64(splitmix64(
            self.seed ^ splitmix64(pass),
        )));
        order
    }

    fn index(&self, world: usize) -> Result<usize, DealerError> {
        if let Some(first) = self.fresh {
            return world
                .checked_sub(first)
                .filter(|&i| i < self.worlds.len())
                .ok_or(DealerError::UnknownWorld(world));
        }
        self.worlds
            .iter()
            .position(|&w| w == world)
            .ok_or(DealerError::UnknownWorld(world))
    }

    /// The world to assign next, counted as in flight until [`Dealer::complete`] or
    /// [`Dealer::release`]: the oldest released assignment if any, otherwise the first world
    /// of the smallest share in the current pass's order (a fresh dealer: the next new id).
    pub fn deal(&mut self) -> usize {
        if let Some(index) = self.pending.pop_front() {
            self.in_flight[index] += 1;
            return self.worlds[index];
        }
        if let Some(first) = self.fresh {
            let world = first + self.worlds.len();
            self.worlds.push(world);
            self.completed.push(0);
            self.in_flight.push(1);
            self.shares.push(1);
            return world;
        }
        let index = *self
            .order
            .iter()
            .find(|&&i| self.shares[i] == self.pass)
            .expect("the smallest share equals the pass, so some world has it");
        self.in_flight[index] += 1;
        self.shares[index] += 1;
        if self.shares.iter().all(|&share| share > self.pass) {
            self.pass += 1;
            self.order = self.pass_order(self.pass);
        }
        self.worlds[index]
    }

    /// Records that one in-flight assignment of `world` finished.
    pub fn complete(&mut self, world: usize) -> Result<(), DealerError> {
        let index = self.take_in_flight(world)?;
        self.completed[index] += 1;
        Ok(())
    }

    /// Returns one in-flight assignment of `world` to the pool (its lease expired): the world
    /// keeps its share and is dealt again before any other world (after earlier releases).
    pub fn release(&mut self, world: usize) -> Result<(), DealerError> {
        let index = self.take_in_flight(world)?;
        self.pending.push_back(index);
        Ok(())
    }

    /// Releases every in-flight assignment (in world-list order), e.g. when leases do not
    /// survive a restart.
    pub fn release_all_in_flight(&mut self) {
        for index in 0..self.worlds.len() {
            for _ in 0..std::mem::take(&mut self.in_flight[index]) {
                self.pending.push_back(index);
            }
        }
    }

    fn take_in_flight(&mut self, world: usize) -> Result<usize, DealerError> {
        let index = self.index(world)?;
        if self.in_flight[index] == 0 {
            return Err(DealerError::NothingInFlight(world));
        }
        self.in_flight[index] -= 1;
        Ok(index)
    }

    /// The worlds, in the order given to [`Dealer::new`] (a fresh dealer: those dealt so far).
    pub fn worlds(&self) -> &[usize] {
        &self.worlds
    }

    /// Per-world counts, in the order of [`Dealer::worlds`].
    pub fn counts(&self) -> Vec<WorldCount> {
        let mut pending = vec![0; self.worlds.len()];
        for &index in &self.pending {
            pending[index] += 1;
        }
        (0..self.worlds.len())
            .map(|i| WorldCount {
                world: self.worlds[i],
                completed: self.completed[i],
                in_flight: self.in_flight[i],
                pending: pending[i],
            })
            .collect()
    }
}

impl TryFrom<DealerState> for Dealer {
    type Error = DealerError;

    fn try_from(state: DealerState) -> Result<Self, DealerError> {
        Self::from_state(state)
    }
}

impl From<Dealer> for DealerState {
    fn from(dealer: Dealer) -> Self {
        let pending = dealer.pending.iter().map(|&index| dealer.worlds[index]).collect();
        Self {
            worlds: dealer.worlds,
            seed: dealer.seed,
            completed: dealer.completed,
            in_flight: dealer.in_flight,
            pending,
            fresh: dealer.fresh,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    fn spread(counts: &[WorldCount], share: impl Fn(&WorldCount) -> u64) -> u64 {
        let shares: Vec<u64> = counts.iter().map(share).collect();
        shares.iter().max().unwrap() - shares.iter().min().unwrap()
    }

    #[test]
    fn a_fresh_dealer_deals_each_id_once_and_redeals_releases_first() {
        let mut dealer = Dealer::of_pool(WorldPool::Fresh { first: 1_000 }, 7).unwrap();
        assert_eq!(
            (dealer.deal(), dealer.deal(), dealer.deal()),
            (1_000, 1_001, 1_002)
        );
        dealer.complete(1_000).unwrap();
        dealer.release(1_002).unwrap();
        assert_eq!(dealer.deal(), 1_002, "a released assignment goes first");
        assert_eq!(dealer.deal(), 1_003);
        assert_eq!(dealer.complete(999), Err(DealerError::UnknownWorld(999)));
        assert_eq!(dealer.complete(1_004), Err(DealerError::UnknownWorld(1_004)));
        assert_eq!(dealer.complete(1_000), Err(DealerError::NothingInFlight(1_000)));
        let counts = dealer.counts();
        assert_eq!(dealer.worlds(), &[1_000, 1_001, 1_002, 1_003]);
        assert_eq!(counts.iter().map(|c| c.completed).sum::<u64>(), 1);
        assert_eq!(counts.iter().map(|c| c.in_flight).sum::<u64>(), 3);
        // A restart: the in-flight ones come back first, then the run goes on where it was.
        let text = serde_json::to_string(&dealer).unwrap();
        let mut back: Dealer = serde_json::from_str(&text).unwrap();
        back.release_all_in_flight();
        assert_eq!((back.deal(), back.deal(), back.deal()), (1_001, 1_002, 1_003));
        assert_eq!(back.deal(), 1_004);
    }

    #[test]
    fn a_listed_dealer_state_has_no_fresh_field_and_a_bad_fresh_state_is_refused() {
        let listed = serde_json::to_string(&Dealer::new(vec![3, 4], 1).unwrap()).unwrap();
        assert!(!listed.contains("fresh"), "{listed}");
        let bad = r#"{"worlds":[5,7],"seed":1,"completed":[1,1],"in_flight":[0,0],"pending":[],"fresh":5}"#;
        let err = serde_json::from_str::<Dealer>(bad).unwrap_err().to_string();
        assert!(err.contains("lists world 7 at position 1"), "{err}");
    }

    #[test]
    fn rejects_empty_and_duplicate_world_lists() {
        assert_eq!(Dealer::new(vec![], 1), Err(DealerError::NoWorlds));
        assert_eq!(Dealer::new(vec![4, 2, 4], 1), Err(DealerError::DuplicateWorld(4)));
    }

    #[test]
    fn every_pass_deals_each_world_once_in_a_fresh_order() {
        let worlds: Vec<usize> = (100..120).collect();
        let mut dealer = Dealer::new(worlds.clone(), 9).unwrap();
        let mut passes = Vec::new();
        for _ in 0..4 {
            let pass: Vec<usize> = (0..worlds.len()).map(|_| dealer.deal()).collect();
            let mut sorted = pass.clone();
            sorted.sort_unstable();
            assert_eq!(sorted, worlds);
            passes.push(pass);
        }
        assert!(
            passes.windows(2).all(|pair| pair[0] != pair[1]),
            "orders repeat between passes"
        );
    }

    #[test]
    fn same_seed_same_sequence_different_seed_different_sequence() {
        let run = |seed| {
            let mut dealer = Dealer::new((0..30).collect(), seed).unwrap();
            (0..90).map(|_| dealer.deal()).collect::<Vec<_>>()
        };
        assert_eq!(run(5), run(5));
        assert_ne!(run(5), run(6));
    }

    #[test]
    fn released_world_is_dealt_next() {
        let mut dealer = Dealer::new((0..10).collect(), 3).unwrap();
        let first = dealer.deal();
        let second = dealer.deal();
        dealer.release(first).unwrap();
        assert_eq!(dealer.deal(), first);
        dealer.release(second).unwrap();
        dealer.release(first).unwrap();
        assert_eq!((dealer.deal(), dealer.deal()), (second, first));
    }

    #[test]
    fn complete_and_release_check_the_world() {
        let mut dealer = Dealer::new(vec![1, 2], 0).unwrap();
        assert_eq!(dealer.complete(7), Err(DealerError::UnknownWorld(7)));
        assert_eq!(dealer.release(1), Err(DealerError::NothingInFlight(1)));
        let world = dealer.deal();
        dealer.complete(world).unwrap();
        assert_eq!(dealer.complete(world), Err(DealerError::NothingInFlight(world)));
    }

    #[test]
    fn shares_stay_within_one_over_random_operations() {
        let mut rng = Pcg64Mcg::seed_from_u64(2024);
        for trial in 0..20 {
            let n = rng.random_range(1..40);
            let mut dealer = Dealer::new((0..n).map(|w| w * 3).collect(), trial).unwrap();
            let mut in_flight: Vec<usize> = Vec::new();
            for _ in 0..5_000 {
                match rng.random_range(0..10) {
                    0..=4 => in_flight.push(dealer.deal()),
                    5..=7 if !in_flight.is_empty() => {
                        let world = in_flight.swap_remove(rng.random_range(0..in_flight.len()));
                        dealer.complete(world).unwrap();
                    }
                    8..=9 if !in_flight.is_empty() => {
                        let world = in_flight.swap_remove(rng.random_range(0..in_flight.len()));
                        let was_empty = dealer.pending.is_empty();
                        dealer.release(world).unwrap();
                        if was_empty && rng.random_bool(0.5) {
                            assert_eq!(dealer.deal(), world, "a released world must be dealt next");
                            in_flight.push(world);
                        }
                    }
                    _ => {}
                }
                let counts = dealer.counts();
                assert!(spread(&counts, |c| c.completed + c.in_flight + c.pending) <= 1);
                if dealer.pending.is_empty() {
                    assert!(spread(&counts, |c| c.completed + c.in_flight) <= 1);
                }
                let dealt: u64 = counts.iter().map(|c| c.in_flight).sum();
                assert_eq!(dealt, in_flight.len() as u64);
            }
        }
    }

    #[test]
    fn serde_round_trip_continues_the_same_sequence() {
        let mut dealer = Dealer::new((0..12).collect(), 77).unwrap();
        let dealt: Vec<usize> = (0..17).map(|_| dealer.deal()).collect();
        dealer.complete(dealt[0]).unwrap();
        dealer.release(dealt[1]).unwrap();
        let json = serde_json::to_string(&dealer).unwrap();
        let mut restored: Dealer = serde_json::from_str(&json).unwrap();
        assert_eq!(restored, dealer);
        let a: Vec<usize> = (0..30).map(|_| dealer.deal()).collect();
        let b: Vec<usize> = (0..30).map(|_| restored.deal()).collect();
        assert_eq!(a, b);
    }

    #[test]
    fn deserialization_rejects_inconsistent_state() {
        let json = r#"{"worlds":[1,2],"seed":0,"completed":[3,0],"in_flight":[0,0],"pending":[]}"#;
        let error = serde_json::from_str::<Dealer>(json).unwrap_err().to_string();
        assert!(error.contains("more than one apart"), "{error}");
    }

    #[test]
    fn release_all_in_flight_keeps_shares_and_redeals_first() {
        let mut dealer = Dealer::new((0..5).collect(), 1).unwrap();
        let a = dealer.deal();
        let b = dealer.deal();
        dealer.release_all_in_flight();
        let mut redealt = vec![dealer.deal(), dealer.deal()];
        redealt.sort_unstable();
        let mut expected = vec![a, b];
        expected.sort_unstable();
        assert_eq!(redealt, expected);
        assert!(dealer.counts().iter().all(|c| c.pending == 0));
    }
}
