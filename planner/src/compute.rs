//! The onboard compute model: what a planning cycle costs on the robot's computer.
//!
//! On a robot, dynamics fidelity is paid for in computation. DDP decrements fidelity "to
//! reduce computation and reach a longer planning horizon within the same computation
//! budget" (DDP paper, §III), and the authors' standalone planner stops each of its threads
//! after 40 ms (`reference/adp-code-notes.md` §4.3). Without a price, the most expensive
//! schedule is always at least as good as a cheap one. This module gives fidelity its price,
//! deterministically (never wall-clock time: the same seed gives the same run on any machine):
//!
//! - every planner counts the [`Work`] of each cycle in the units its cost is made of:
//!   distance-field cells built, candidate samples scored, random numbers drawn, rollout
//!   integration steps, footprint check points;
//! - a [`Platform`] prices each unit (ns) and gives each planner a cycle budget;
//! - *budget*: samples are evaluated in an unbiased order ([`even_order`]) and a sample
//!   starts only while the cycle's spent compute is below the budget; the rest are not
//!   considered (the authors' per-thread time limit);
//! - *latency*: the episode driver ([`crate::run`]) applies the command the modelled compute
//!   time after the scan, and a cycle longer than the control period delays the next cycle
//!   while the robot keeps its previous command ([`periods`]).
//!
//! [`ComputeModel::Free`] prices nothing and keeps the behaviour from before the model.
//!
//! The configuration and the prices ([`Work`], [`UnitCosts`], [`Platform`], [`ComputeConfig`],
//! [`Compute`]) are plain data of [`settings::compute`], re-exported here; this module adds
//! what the planners and drivers do with them: the [`Budget`] a cycle spends, the order samples
//! are evaluated in, and the [`ComputeTally`] of a run.
//!
//! Everything here is pure data and arithmetic (`Copy`, thread-safe); planners and drivers
//! own their counters.

use std::ops::AddAssign;

use serde::{Deserialize, Serialize};

pub use settings::compute::*;

/// What a planner's budget admits, as it evaluates its samples one by one. Planners start a
/// sample only while [`Budget::admits`] holds for the work spent so far in the cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Budget {
    costs: UnitCosts,
    limit_ns: f64,
}

impl Budget {
    /// No limit: every sample is evaluated, in the planner's own order.
    pub const UNLIMITED: Budget = Budget {
        costs: UnitCosts::ZERO,
        limit_ns: f64::INFINITY,
    };

    /// The budget of `compute` (unlimited for `None`).
    pub fn of(compute: Option<&Compute>) -> Budget {
        match compute {
            Some(c) => Budget {
                costs: c.costs,
                limit_ns: c.budget_ns,
            },
            None => Budget::UNLIMITED,
        }
    }

    /// Whether the budget can stop a cycle (planners then evaluate in [`even_order`]).
    pub fn is_limited(&self) -> bool {
        self.limit_ns.is_finite()
    }

    /// Whether a new sample may start after `spent` work this cycle.
    pub fn admits(&self, spent: &Work) -> bool {
        !self.is_limited() || self.costs.cycle_ns(spent) < self.limit_ns
    }
}

/// Writes into `out` an order of `0..n` in which every prefix is spread evenly over the
/// indices: the rank-1 lattice `k * s mod n` with `s` the integer nearest `n / phi` (the
/// golden ratio) that is coprime with `n`. Index 0 comes first. Samples laid out by kind or
/// on a grid (DWA's v-major grid, MPPI's braking and exploring samples, the system's grid,
/// warm starts and extras) are thus all represented in any prefix the budget allows, in
/// proportion.
pub fn even_order(n: usize, out: &mut Vec<u32>) {
    out.clear();
    if n == 0 {
        return;
    }
    let phi = (1.0 + 5f64.sqrt()) / 2.0;
    let mut s = ((n as f64 / phi).round() as usize).max(1);
    while gcd(s, n) != 1 {
        s += 1;
    }
    out.extend((0..n).map(|k| ((k * s) % n) as u32));
}

/// Which samples a budget admits, for planners that evaluate their samples in parallel
/// (the outcome is the same as evaluating them one by one): walks `order`, starting each
/// sample while `budget` admits the cycle's work so far (`spent`, then each admitted
/// sample's `work_of`), sets `admitted[i]` for the samples that start and returns the cycle
/// record (its `work` = `spent` + the admitted samples' work). Unlimited budgets admit every
/// sample.
///
/// # Panics
/// If `admitted` is shorter than an index of `order`.
pub fn admit(
    budget: &Budget,
    spent: Work,
    order: &[u32],
    work_of: impl Fn(usize) -> Work,
    admitted: &mut [bool],
) -> CycleWork {
    let mut c = CycleWork {
        work: spent,
        samples: order.len() as u32,
        evaluated: 0,
    };
    admitted.iter_mut().for_each(|a| *a = false);
    for &i in order {
        if !budget.admits(&c.work) {
            break;
        }
        admitted[i as usize] = true;
        c.work += work_of(i as usize);
        c.evaluated += 1;
    }
    c
}

/// Writes into `out` the order in which a planner evaluates its `n` samples under `budget`:
/// [`even_order`] when the budget can stop the cycle, the planner's own order `0..n` (so an
/// unlimited cycle computes exactly what it did before the model) otherwise.
pub fn evaluation_order(budget: &Budget, n: usize, out: &mut Vec<u32>) {
    if budget.is_limited() {
        even_order(n, out);
    } else {
        out.clear();
        out.extend(0..n as u32);
    }
}

fn gcd(mut a: usize, mut b: usize) -> usize {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

/// Control periods a cycle of `compute_s` seconds occupies: at least one; a cycle whose
/// compute runs past the period makes the planner miss the following timer ticks, so the
/// next cycle starts at the first tick after it finished and the robot keeps its previous
/// command in between.
pub fn periods(compute_s: f64, control_dt: f64) -> u32 {
    // A cycle that ends within a nanosecond of a tick still makes that tick.
    ((compute_s - 1e-9) / control_dt).ceil().max(1.0) as u32
}

/// What the planning cycles of a run did and cost: summed by the episode drivers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ComputeTally {
    /// Planning cycles run.
    pub cycles: u64,
    /// Their work.
    pub work: Work,
    /// Their modelled compute (ms; 0 under the free model).
    pub modelled_ms: f64,
    /// Candidate samples the cycles had.
    pub samples: u64,
    /// Of those, evaluated within the budget.
    pub evaluated_samples: u64,
    /// Cycles the budget stopped before their last sample.
    pub truncated_cycles: u64,
    /// Cycles whose compute ran past the control period (the next cycle started late).
    pub late_cycles: u64,
    /// Cycles in PADP's pressure modes A, B and C ([`crate::padp`]; all 0 unless its
    /// adaptive part runs, and then left out of the JSON).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub pressure_cycles: [u64; 3],
}

fn is_zero(counts: &[u64; 3]) -> bool {
    *counts == [0; 3]
}

impl AddAssign for ComputeTally {
    fn add_assign(&mut self, o: ComputeTally) {
        self.cycles += o.cycles;
        self.work += o.work;
        self.modelled_ms += o.modelled_ms;
        self.samples += o.samples;
        self.evaluated_samples += o.evaluated_samples;
        self.truncated_cycles += o.truncated_cycles;
        self.late_cycles += o.late_cycles;
        for (a, b) in self.pressure_cycles.iter_mut().zip(o.pressure_cycles) {
            *a += b;
        }
    }
}

/// One planning cycle as a planner reports it ([`crate::Trace::cycle`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CycleWork {
    /// The cycle's work.
    pub work: Work,
    /// Candidate samples the cycle had (0 for a cycle without sampling, e.g. recovery).
    pub samples: u32,
    /// Of those, evaluated within the budget.
    pub evaluated: u32,
}

impl ComputeTally {
    /// Adds one cycle that did `c` and took `compute_s` modelled seconds of a period of
    /// `control_dt`.
    pub fn record(&mut self, c: &CycleWork, compute_s: f64, control_dt: f64) {
        self.cycles += 1;
        self.work += c.work;
        self.modelled_ms += compute_s * 1e3;
        self.samples += u64::from(c.samples);
        self.evaluated_samples += u64::from(c.evaluated);
        if c.evaluated < c.samples {
            self.truncated_cycles += 1;
        }
        if periods(compute_s, control_dt) > 1 {
            self.late_cycles += 1;
        }
    }

    /// Mean modelled compute per cycle (ms).
    pub fn ms_per_cycle(&self) -> f64 {
        self.modelled_ms / self.cycles.max(1) as f64
    }

    /// Share of the candidate samples the budget allowed (1 when there were none).
    pub fn evaluated_share(&self) -> f64 {
        if self.samples == 0 {
            1.0
        } else {
            self.evaluated_samples as f64 / self.samples as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn costs() -> UnitCosts {
        UnitCosts {
            cycle_ns: 1000.0,
            cell_ns: 1.0,
            sample_ns: 10.0,
            draw_ns: 2.0,
            step_ns: 3.0,
            point_ns: 4.0,
        }
    }

    #[test]
    fn budget_admits_while_spent_is_below_the_limit() {
        let b = Budget::of(Some(&Compute {
            costs: costs(),
            budget_ns: 1100.0,
        }));
        assert!(b.is_limited());
        let mut w = Work::default();
        assert!(b.admits(&w));
        w.cells = 99;
        assert!(b.admits(&w));
        w.cells = 100;
        assert!(!b.admits(&w));
        assert!(Budget::UNLIMITED.admits(&Work {
            points: u64::MAX / 8,
            ..w
        }));
    }

    #[test]
    fn even_order_is_a_permutation_whose_prefixes_cover_the_grid() {
        let mut o = Vec::new();
        even_order(400, &mut o);
        assert_eq!(o[0], 0);
        let mut sorted = o.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..400).collect::<Vec<u32>>());
        // The first quarter of a 20 x 20 v-major grid meets every v row and every w column.
        let rows: std::collections::BTreeSet<u32> = o[..100].iter().map(|i| i / 20).collect();
        let cols: std::collections::BTreeSet<u32> = o[..100].iter().map(|i| i % 20).collect();
        assert_eq!((rows.len(), cols.len()), (20, 20));
        // MPPI's layout: 28 braking samples (1..=28) and 110 exploring ones (29..=138) of 550
        // keep their shares in the first 100.
        even_order(550, &mut o);
        let brake = o[..100].iter().filter(|&&i| (1..=28).contains(&i)).count();
        let explore = o[..100].iter().filter(|&&i| (29..=138).contains(&i)).count();
        assert!((4..=6).contains(&brake), "{brake}");
        assert!((19..=21).contains(&explore), "{explore}");
        even_order(1, &mut o);
        assert_eq!(o, [0]);
    }

    /// Hand-counted: a fixed 1,000 ns per cycle, 400 ns of map work spent, then samples of
    /// 10 + 3 x 4 + 4 x 5 = 42 ns each (1 sample, 4 steps, 5 points). With a 1,600 ns budget,
    /// samples start at 1,400, 1,442, 1,484, 1,526 and 1,568 ns: exactly 5 fit, the first 5
    /// of the order.
    #[test]
    fn a_budget_admits_exactly_the_samples_that_fit_in_order() {
        let budget = Budget::of(Some(&Compute {
            costs: costs(),
            budget_ns: 1600.0,
        }));
        let spent = Work {
            cells: 400,
            ..Work::default()
        };
        let one = Work {
            samples: 1,
            steps: 4,
            points: 5,
            ..Work::default()
        };
        let mut order = Vec::new();
        even_order(12, &mut order);
        let mut admitted = vec![true; 12];
        let c = admit(&budget, spent, &order, |_| one, &mut admitted);
        assert_eq!((c.samples, c.evaluated), (12, 5));
        assert_eq!(c.work.samples, 5);
        assert_eq!(c.work.points, 25);
        let chosen: Vec<u32> = (0..12u32).filter(|&i| admitted[i as usize]).collect();
        let mut first: Vec<u32> = order[..5].to_vec();
        first.sort_unstable();
        assert_eq!(chosen, first);
        let all = admit(&Budget::UNLIMITED, spent, &order, |_| one, &mut admitted);
        assert_eq!(all.evaluated, 12);
        assert!(admitted.iter().all(|&a| a));
    }

    #[test]
    fn a_cycle_past_the_period_occupies_the_next_ticks() {
        assert_eq!(periods(0.0, 0.05), 1);
        assert_eq!(periods(0.05, 0.05), 1);
        assert_eq!(periods(0.0501, 0.05), 2);
        assert_eq!(periods(0.1, 0.05), 2);
        assert_eq!(periods(0.12, 0.05), 3);
    }
}
