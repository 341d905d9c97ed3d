//! `adp bench compute`: measures what each unit of planner work costs on this machine and
//! derives the `jackal-onboard-v2` compute platform from it ([`planner::compute`]).
//!
//! Every planner (DWA, MPPI, Log-MPPI, the system) runs the vanilla, DDP and three constant
//! decremental schedules at 1.5 m/s on the first training worlds, one thread, free compute
//! model, each at three sample counts (`AXIS_SCALES`); every planning call's counted
//! [`Work`] and its CPU time (the thread's CPU clock, so the load of other processes does not
//! count) are recorded. For each planner, a non-negative least-squares fit of time on
//! (1, cells, samples, draws, steps, points) gives its unit costs here: the planners do
//! different work per unit, and a pooled fit priced a system rollout step (which scores its
//! obstacle terms) like a DWA step (a table lookup). The sample counts vary because at one
//! count per planner a per-sample cost cannot be told from a per-cycle one. The platform
//! scales every planner's costs by one factor, so that the system's DDP cycle takes 40 ms at
//! its 95th percentile (the authors' per-thread limit for their 550 DDP samples), and gives
//! each planner the budget its own DDP cycle (at its configured sample count) needs at the
//! 95th percentile. The result is printed as a `[compute.platform]` table.

use anyhow::Context;
use planner::compute::{PlannerBudgets, PlannerCosts, Platform, UnitCosts};
use planner::{PlanInput, Planner, Schedule, Trace, Work};
use sim::robot::Twist;

use eval::EvalConfig;
use planner::PlannerKind;

use crate::{figure, Figure};

/// The anchor: the system's DDP cycle at its 95th percentile on the reference platform (ms).
const SYSTEM_DDP_P95_MS: f64 = 40.0;

/// Multipliers of each sampling axis in the fit's design (DWA's and the system's v and w
/// grid axes; MPPI's and Log-MPPI's sample count by their square): the configured count
/// (1) and about a quarter and 2.25 times as many samples.
pub(crate) const AXIS_SCALES: [f64; 3] = [0.5, 1.0, 1.5];

/// One planning call: the planner, whether the schedule was DDP, its work and CPU time (ns).
pub(crate) struct Call {
    /// The planner.
    pub(crate) planner: PlannerKind,
    /// Whether the schedule was DDP.
    pub(crate) ddp: bool,
    /// The sampling axes' multiplier (1: the configured sample count).
    pub(crate) axis_scale: f64,
    /// The work the call counted.
    pub(crate) work: Work,
    /// The calling thread's CPU time over the call (ns).
    pub(crate) ns: f64,
}

/// A planner that records each call's work and time.
struct Timed<'a> {
    inner: Box<dyn Planner>,
    kind: PlannerKind,
    ddp: bool,
    axis_scale: f64,
    calls: &'a mut Vec<Call>,
}

impl Planner for Timed<'_> {
    fn name(&self) -> &'static str {
        self.inner.name()
    }

    fn plan(&mut self, input: &PlanInput<'_>) -> Twist {
        let t = thread_cpu_ns();
        let cmd = self.inner.plan(input);
        let ns = thread_cpu_ns() - t;
        self.calls.push(Call {
            planner: self.kind,
            ddp: self.ddp,
            axis_scale: self.axis_scale,
            work: self.inner.trace().cycle.work,
            ns,
        });
        cmd
    }

    fn trace(&self) -> &Trace {
        self.inner.trace()
    }

    fn trace_mut(&mut self) -> &mut Trace {
        self.inner.trace_mut()
    }
}

/// CPU time of the calling thread (ns): other processes' load does not count.
fn thread_cpu_ns() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant Linux supports.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 * 1e9 + ts.tv_nsec as f64
}

/// Solves the least-squares fit `y ~ X b` over the columns in `active` (normal equations,
/// Gaussian elimination with partial pivoting); inactive coefficients are 0.
fn least_squares(x: &[[f64; 6]], y: &[f64], active: &[bool; 6]) -> [f64; 6] {
    let cols: Vec<usize> = (0..6).filter(|&j| active[j]).collect();
    let k = cols.len();
    let mut a = vec![vec![0.0; k + 1]; k];
    for (row, &yi) in x.iter().zip(y) {
        for (p, &cp) in cols.iter().enumerate() {
            for (q, &cq) in cols.iter().enumerate() {
                a[p][q] += row[cp] * row[cq];
            }
            a[p][k] += row[cp] * yi;
        }
    }
    for i in 0..k {
        let piv = (i..k)
            .max_by(|&r, &s| a[r][i].abs().total_cmp(&a[s][i].abs()))
            .unwrap_or(i);
        a.swap(i, piv);
        let d = a[i][i];
        if d.abs() < 1e-30 {
            continue;
        }
        let pivot = a[i].clone();
        for (r, row) in a.iter_mut().enumerate() {
            if r != i {
                let f = row[i] / d;
                for (x, &p) in row[i..].iter_mut().zip(&pivot[i..]) {
                    *x -= f * p;
                }
            }
        }
    }
    let mut b = [0.0; 6];
    for (p, &c) in cols.iter().enumerate() {
        b[c] = if a[p][p].abs() < 1e-30 {
            0.0
        } else {
            a[p][k] / a[p][p]
        };
    }
    b
}

/// Non-negative least squares by elimination: refits without the most negative coefficient
/// until none is negative. Units that no call used get 0.
fn nonnegative_fit(x: &[[f64; 6]], y: &[f64]) -> [f64; 6] {
    // A unit no call used has no cost to fit (and would make the normal equations singular).
    let mut active: [bool; 6] = std::array::from_fn(|j| x.iter().any(|r| r[j] != 0.0));
    loop {
        let b = least_squares(x, y, &active);
        let worst = (0..6)
            .filter(|&j| active[j] && b[j] < 0.0)
            .min_by(|&i, &j| b[i].total_cmp(&b[j]));
        match worst {
            Some(j) => active[j] = false,
            None => return b,
        }
    }
}

/// The non-negative least-squares unit costs of `calls` (time on 1, cells, samples, draws,
/// steps, points) and the R^2 of the fit.
fn fit(calls: &[&Call]) -> (UnitCosts, f64) {
    let x: Vec<[f64; 6]> = calls
        .iter()
        .map(|c| {
            let [cl, s, d, st, p] = c.work.as_array().map(|u| u as f64);
            [1.0, cl, s, d, st, p]
        })
        .collect();
    let y: Vec<f64> = calls.iter().map(|c| c.ns).collect();
    let b = nonnegative_fit(&x, &y);
    let costs = UnitCosts {
        cycle_ns: b[0],
        cell_ns: b[1],
        sample_ns: b[2],
        draw_ns: b[3],
        step_ns: b[4],
        point_ns: b[5],
    };
    let mean = y.iter().sum::<f64>() / y.len().max(1) as f64;
    let (mut ss_res, mut ss_tot) = (0.0, 0.0);
    for (c, &yi) in calls.iter().zip(&y) {
        ss_res += (yi - costs.cycle_ns(&c.work)).powi(2);
        ss_tot += (yi - mean).powi(2);
    }
    (costs, 1.0 - ss_res / ss_tot.max(1e-30))
}

/// The table of `kind` in `costs`.
fn costs_mut(costs: &mut PlannerCosts, kind: PlannerKind) -> &mut UnitCosts {
    match kind {
        PlannerKind::Dwa => &mut costs.dwa,
        PlannerKind::Mppi => &mut costs.mppi,
        PlannerKind::LogMppi => &mut costs.log_mppi,
        PlannerKind::System => &mut costs.system,
    }
}

pub(crate) fn percentile(mut v: Vec<f64>, q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// `cfg` with every planner's sampling axes scaled by `k`: DWA's and the system's v and w
/// grid axes (and the system's warm-start copies) by `k`, MPPI's and Log-MPPI's sample count
/// by `k^2`; at least one sample per axis.
fn resized(cfg: &EvalConfig, k: f64) -> EvalConfig {
    let axis = |n: usize| ((n as f64 * k).round() as usize).max(1);
    let count = |n: usize| ((n as f64 * k * k).round() as usize).max(1);
    let mut c = cfg.clone();
    c.dwa.v_samples = axis(c.dwa.v_samples);
    c.dwa.w_samples = axis(c.dwa.w_samples);
    c.system.v_samples = axis(c.system.v_samples);
    c.system.w_samples = axis(c.system.w_samples);
    c.system.warm_samples = axis(c.system.warm_samples);
    c.mppi.samples = count(c.mppi.samples);
    c.log_mppi.samples = count(c.log_mppi.samples);
    c
}

/// Drives every planner in `kinds` with every schedule on the first `worlds` training worlds
/// at 1.5 m/s, one thread, free compute model, at every sampling-axis multiplier of
/// `axis_scales` ([`AXIS_SCALES`]; `[1.0]` for the configured planners only), and returns
/// every planning call's work and CPU time. The schedules are `(schedule, is DDP)`.
pub(crate) fn measure_calls(
    worlds: usize,
    kinds: &[PlannerKind],
    schedules: &[(Schedule, bool)],
    axis_scales: &[f64],
) -> anyhow::Result<Vec<Call>> {
    let mut base = EvalConfig::load(None)?;
    base.compute = planner::ComputeConfig::FREE;
    let ids: Vec<usize> = sim::splits::select("train")?
        .into_iter()
        .take(worlds.max(1))
        .collect();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let mut calls = Vec::with_capacity(1 << 20);
    pool.install(|| -> anyhow::Result<()> {
        for &axis_scale in axis_scales {
            let cfg = resized(&base, axis_scale);
            for &kind in kinds {
                for (sched, ddp) in schedules {
                    for &w in &ids {
                        let world = sim::catalog::world(w).with_context(|| format!("world {w}"))?;
                        let seed = eval::run_seed(7, w, 0);
                        let mut timed = Timed {
                            inner: kind.build(&cfg.planners(), seed),
                            kind,
                            ddp: *ddp,
                            axis_scale,
                            calls: &mut calls,
                        };
                        planner::run::run_episode(
                            world,
                            cfg.episode,
                            &mut timed,
                            sched,
                            1.5,
                            seed,
                            None,
                            |_, _, _| {},
                        );
                    }
                }
            }
        }
        Ok(())
    })?;
    Ok(calls)
}

/// Runs the measurement on the first `worlds` training worlds and prints the fit and the
/// platform.
pub fn run(worlds: usize) -> anyhow::Result<Vec<Figure>> {
    let mut schedules = vec![(Schedule::vanilla(), false), (Schedule::ddp_default(), true)];
    for (p, t, n, alpha) in [
        (1.5, 2.0, 10, 0.3),
        (1.0, 1.6, 15, 0.6),
        (1.3, 1.9, 18, 0.3),
        (1.7, 2.2, 22, 0.0),
    ] {
        schedules.push((Schedule::decremental(p, t, n, alpha, 20)?, false));
    }
    let kinds = PlannerKind::ALL;
    let calls = measure_calls(worlds, &kinds, &schedules, &AXIS_SCALES)?;
    // Per planner: its unit costs here and the R^2 of their fit to its calls.
    let mut here = PlannerCosts::shared(UnitCosts::ZERO);
    let mut r2 = [0.0; 4];
    for (k, kind) in kinds.iter().enumerate() {
        let own: Vec<&Call> = calls.iter().filter(|c| c.planner == *kind).collect();
        let (costs, fit_r2) = fit(&own);
        *costs_mut(&mut here, *kind) = costs;
        r2[k] = fit_r2;
    }
    // The planner's configured DDP cycles (the budgets' reference).
    let ddp_calls = |k: PlannerKind| {
        calls
            .iter()
            .filter(move |c| c.planner == k && c.ddp && c.axis_scale == 1.0)
    };
    let ddp_p95 = |k: PlannerKind, costs: &PlannerCosts| {
        let c = costs.of(k.name()).expect("one of the crate's planners");
        percentile(ddp_calls(k).map(|call| c.cycle_ns(&call.work)).collect(), 0.95)
    };
    let scale = SYSTEM_DDP_P95_MS * 1e6 / ddp_p95(PlannerKind::System, &here).max(1.0);
    let costs = here.scaled(scale);
    let budget = |k| (ddp_p95(k, &costs) / 1e6 * 100.0).round() / 100.0;
    let platform = Platform {
        costs,
        budget_ms: PlannerBudgets {
            dwa: budget(PlannerKind::Dwa),
            mppi: budget(PlannerKind::Mppi),
            log_mppi: budget(PlannerKind::LogMppi),
            system: budget(PlannerKind::System),
        },
    };
    println!(
        "unit costs on this machine (ns), fitted per planner over {} planning calls:",
        calls.len()
    );
    for (k, kind) in kinds.iter().enumerate() {
        let c = here.of(kind.name()).expect("one of the crate's planners");
        println!("  {:<9} R^2 {:.3}: {c:?}", kind.name(), r2[k]);
    }
    println!("scale to the reference platform: x{scale:.2}");
    println!(
        "[compute.platform]\n{}",
        toml::to_string(&platform).unwrap_or_default()
    );
    let mut figs = Vec::new();
    for (k, kind) in kinds.iter().enumerate() {
        figs.push(figure(
            format!("compute model fit of {}, R^2 of per-call CPU time", kind.name()),
            r2[k],
            "",
        ));
    }
    for k in kinds {
        let c = here.of(k.name()).expect("one of the crate's planners");
        let measured = percentile(ddp_calls(k).map(|call| call.ns).collect(), 0.5);
        let fitted = percentile(ddp_calls(k).map(|call| c.cycle_ns(&call.work)).collect(), 0.5);
        figs.push(figure(
            format!(
                "{} DDP cycle here, median: measured (fit {:.3} ms)",
                k.name(),
                fitted / 1e6
            ),
            measured / 1e6,
            "ms",
        ));
    }
    Ok(figs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fit_recovers_nonnegative_unit_costs() {
        // y = 500 + 2 cells + 3 points, with an irrelevant column.
        let x: Vec<[f64; 6]> = (0..50)
            .map(|i| {
                let i = f64::from(i);
                [
                    1.0,
                    10.0 * i,
                    (i * 7.0) % 5.0,
                    0.0,
                    (i * 3.0) % 11.0,
                    (i * i) % 13.0,
                ]
            })
            .collect();
        let y: Vec<f64> = x.iter().map(|r| 500.0 + 2.0 * r[1] + 3.0 * r[5]).collect();
        let b = nonnegative_fit(&x, &y);
        for (got, want) in b.iter().zip([500.0, 2.0, 0.0, 0.0, 0.0, 3.0]) {
            assert!((got - want).abs() < 1e-6, "{b:?}");
        }
    }
}
