//! What one control cycle costs at the BARN scale and at the envelope's edge, per planner
//! (DDP, no policy), in wall time on one thread, with the costmap's size:
//!
//! ```text
//! cargo run --release -p adp-runtime --example envelope_edge
//! ```
//!
//! * `barn`: BARN world 10 from its start to its goal (about 10 m away).
//! * `edge`: the same world and start, the goal 48 m away on the diagonal (inside
//!   `max_goal_distance_m`'s default of 50 m as the robot moves): about the largest costmap
//!   the default envelope allows.
//! * `edge, walled`: as `edge`, but every beam returns at 1 m (a wall around the robot's
//!   front, open behind it): each replan searches around it on the largest costmap.
//!
//! Each scenario runs `CYCLES` cycles; the simulated robot moves with the commands (its time is
//! not counted). The last line is the process's peak resident memory.

use std::time::Instant;

use adp_runtime::{sim_robot, CycleInput, Navigator, RuntimeOptions};
use eval::EvalConfig;
use planner::PlannerKind;
use sim::episode::{Episode, Status};
use sim::geometry::Vec2;

const CYCLES: usize = 200;

/// How the scenario changes what the robot sees.
#[derive(Clone, Copy)]
enum Scenario {
    Barn,
    Edge,
    EdgeWalled,
}

impl Scenario {
    fn name(self) -> &'static str {
        match self {
            Scenario::Barn => "barn",
            Scenario::Edge => "edge",
            Scenario::EdgeWalled => "edge, walled",
        }
    }
}

/// Every cycle's wall time (ns) and the costmap's cell count.
fn run(kind: PlannerKind, scenario: Scenario) -> (Vec<f64>, usize) {
    let cfg = EvalConfig::load(None).expect("the embedded settings");
    let mut nav = Navigator::new(&cfg, RuntimeOptions::new(kind, 1.5), None).expect("a navigator");
    let world = &sim::catalog::barn_worlds()[10];
    let mut ep = Episode::new(world, *nav.episode(), 3);
    let start = ep.believed_pose().position();
    let edge = start + Vec2::new(34.0, 34.0);
    let wall = vec![1.0; nav.lidar().angles().len()];
    let mut times = Vec::with_capacity(CYCLES);
    for _ in 0..CYCLES {
        let seen = sim_robot::observe(&ep);
        let input = match scenario {
            Scenario::Barn => seen,
            Scenario::Edge => CycleInput { goal: edge, ..seen },
            Scenario::EdgeWalled => CycleInput {
                goal: edge,
                ranges: &wall,
                ..seen
            },
        };
        let t0 = Instant::now();
        let out = nav
            .cycle(&input)
            .unwrap_or_else(|e| panic!("{} {}: {e}", kind.name(), scenario.name()));
        times.push(t0.elapsed().as_nanos() as f64);
        if sim_robot::apply(&mut ep, out.command, out.planned, out.compute_s) != Status::Running {
            ep = Episode::new(world, *nav.episode(), 3);
        }
    }
    let map = nav.nav().expect("a run").costmap();
    (times, map.nx() * map.ny())
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

/// The process's peak resident memory (kB), from /proc (0 where there is none).
fn peak_rss_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse().ok())
        })
        .unwrap_or(0)
}

fn main() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("a thread pool");
    println!("| planner | scenario | costmap cells | p50 (ms) | p99 (ms) | max (ms) |");
    println!("|---|---|---|---|---|---|");
    for kind in PlannerKind::ALL {
        for scenario in [Scenario::Barn, Scenario::Edge, Scenario::EdgeWalled] {
            let (mut times, cells) = pool.install(|| run(kind, scenario));
            times.sort_by(f64::total_cmp);
            println!(
                "| {} | {} | {cells} | {:.3} | {:.3} | {:.3} |",
                kind.name(),
                scenario.name(),
                percentile(&times, 0.5) / 1e6,
                percentile(&times, 0.99) / 1e6,
                times[times.len() - 1] / 1e6
            );
        }
    }
    println!("peak resident memory: {:.1} MB", peak_rss_kb() as f64 / 1024.0);
}
