//! `adp bench runtime`: what one control cycle of the robot runtime (`adp-runtime`) costs in
//! wall time, per planner, with DDP and with a trained policy, against the compute model's
//! budget for that planner.
//!
//! Every planner drives the first training worlds at 1.5 m/s through
//! [`adp_runtime::Navigator::cycle`] on one thread, the simulator standing in for the robot
//! (its time is not counted). Each call is timed: the scan's checks, the costmap and global
//! path, the policy's step when an agent period begins, and the planning cycle. The table
//! gives p50 / p99 / max against the `[compute]` budget of the default model (the Jackal's
//! onboard computer; this machine is another), and the policy's inference time with its
//! share of the cycles it runs in (one inference per agent period).
//!
//! Figures: the p99 of each planner and fidelity, with the budget as its bound.

use std::path::Path;
use std::time::Instant;

use adp_runtime::{load_policy, sim_robot, Navigator, RuntimeOptions};
use anyhow::Context;
use eval::EvalConfig;
use planner::PlannerKind;
use sim::episode::{Episode, Status};

use crate::compute::percentile;
use crate::{figure, Figure};

/// The policy the benchmark runs when none is given: the runtime's example export.
pub const EXAMPLE_POLICY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../runtime/examples/policy");

/// Drives `world` through `nav` and returns every cycle's wall time (ns).
fn timed_episode(nav: &mut Navigator, world: &sim::World, seed: u64, out: &mut Vec<f64>) {
    let mut ep = Episode::new(world, *nav.episode(), seed);
    loop {
        let input = sim_robot::observe(&ep);
        let t0 = Instant::now();
        let decided = nav.cycle(&input);
        out.push(t0.elapsed().as_nanos() as f64);
        let Ok(o) = decided else {
            ep.abandon();
            return;
        };
        if sim_robot::apply(&mut ep, o.command, o.planned, o.compute_s) != Status::Running {
            return;
        }
    }
}

/// Mean wall time of one inference of the policy at `dir` (ns), over observations in [-1, 1].
fn inference_ns(dir: &Path) -> anyhow::Result<f64> {
    let p = load_policy(dir)?;
    let obs: Vec<f32> = (0..p.net.obs_dim())
        .map(|i| ((i * 37 % 200) as f32 / 100.0) - 1.0)
        .collect();
    let mut out = vec![0.0f32; p.net.act_dim()];
    let mut scratch = actor::policy::Scratch::default();
    let n = 2000;
    p.net.act(&obs, &mut out, &mut scratch);
    let t0 = Instant::now();
    for _ in 0..n {
        p.net.act(std::hint::black_box(&obs), &mut out, &mut scratch);
    }
    Ok(t0.elapsed().as_nanos() as f64 / n as f64)
}

/// Runs the measurement on the first `worlds` training worlds with the policy export at
/// `policy` and prints the table.
pub fn run(worlds: usize, policy: &Path) -> anyhow::Result<Vec<Figure>> {
    let cfg = EvalConfig::load(None)?;
    let ids: Vec<usize> = sim::splits::select("train")?
        .into_iter()
        .take(worlds.max(1))
        .collect();
    let infer_ns = inference_ns(policy).with_context(|| format!("policy {}", policy.display()))?;
    let agent_period = load_policy(policy)?.env.agent_period_cycles as f64;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    println!(
        "runtime control cycle, wall time on one thread ({} training worlds at 1.5 m/s; policy \
         inference {:.1} us, once per {agent_period} cycles)",
        ids.len(),
        infer_ns / 1e3
    );
    println!(
        "| planner | schedule | cycles | p50 (ms) | p99 (ms) | max (ms) | budget (ms) | policy share (%) |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let mut figs = Vec::new();
    for kind in PlannerKind::ALL {
        let budget_ms = cfg
            .compute
            .resolve(kind.name())?
            .map_or(f64::INFINITY, |c| c.budget_ns / 1e6);
        for with_policy in [false, true] {
            let mut times = Vec::with_capacity(1 << 16);
            pool.install(|| -> anyhow::Result<()> {
                for &w in &ids {
                    let world = sim::catalog::world(w).with_context(|| format!("world {w}"))?;
                    let options = RuntimeOptions {
                        seed: eval::run_seed(7, w, 0),
                        ..RuntimeOptions::new(kind, 1.5)
                    };
                    let p = with_policy.then(|| load_policy(policy)).transpose()?;
                    let mut nav = Navigator::new(&cfg, options, p)?;
                    timed_episode(&mut nav, world, eval::run_seed(7, w, 0), &mut times);
                }
                Ok(())
            })?;
            let mean = times.iter().sum::<f64>() / times.len().max(1) as f64;
            let (p50, p99) = (percentile(times.clone(), 0.5), percentile(times.clone(), 0.99));
            let max = times.iter().copied().fold(0.0, f64::max);
            let label = if with_policy { "policy" } else { "ddp" };
            let share = if with_policy {
                format!("{:.1}", 100.0 * infer_ns / (agent_period * mean))
            } else {
                String::new()
            };
            println!(
                "| {} | {label} | {} | {:.3} | {:.3} | {:.3} | {budget_ms:.1} | {share} |",
                kind.name(),
                times.len(),
                p50 / 1e6,
                p99 / 1e6,
                max / 1e6
            );
            figs.push(
                figure(
                    format!("runtime cycle p99, {} {label}", kind.name()),
                    p99 / 1e6,
                    "ms",
                )
                .at_most(budget_ms),
            );
        }
    }
    Ok(figs)
}
