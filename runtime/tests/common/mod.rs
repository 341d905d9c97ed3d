//! What the runtime's bad-input tests share: the shipped example policy, a recorded drive of
//! BARN world 10 and the cycle input made of one of its periods.

use std::path::{Path, PathBuf};

use adp_runtime::{sim_robot, CycleInput, Navigator, Odometry};
use sim::episode::Episode;
use sim::geometry::Vec2;

/// The example policy shipped with the crate.
pub fn policy_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/policy")
}

/// The inputs (ranges, odometry, goal) of the first `n` control periods of BARN world 10,
/// driven by `nav`.
pub fn recorded(mut nav: Navigator, n: usize) -> Vec<(Vec<f64>, Odometry, Vec2)> {
    let world = &sim::catalog::barn_worlds()[10];
    let mut ep = Episode::new(world, *nav.episode(), 3);
    let mut out = Vec::new();
    for _ in 0..n {
        let seen = sim_robot::observe(&ep);
        let cycle = nav.cycle(&seen).unwrap();
        out.push((seen.ranges.to_vec(), seen.odom, seen.goal));
        sim_robot::apply(&mut ep, cycle.command, cycle.planned, cycle.compute_s);
    }
    out
}

/// One period's cycle input, without a global path.
pub fn input(ranges: &[f64], odom: Odometry, goal: Vec2) -> CycleInput<'_> {
    CycleInput {
        stamp_s: odom.stamp_s,
        ranges,
        odom,
        goal,
        global_path: None,
    }
}
