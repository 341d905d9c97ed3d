//! A simulated robot for a [`Navigator`](crate::Navigator): a BARN [`Episode`] whose sensors
//! report what a robot's would ([`observe`]) and whose base takes a cycle's decision
//! ([`apply`]). The runtime's tests, its benchmark and the C and Python bindings' simulated
//! robots all drive worlds through these two functions, the way `adp eval` drives them.

use sim::episode::{Episode, Status};
use sim::robot::Twist;

use crate::input::{CycleInput, Odometry};

/// The navigator's inputs now: the episode's scan, its believed pose (the localisation a
/// robot has) and measured velocity, stamped with the simulation clock, and the world's goal.
/// No global path: the navigator plans its own. Borrows the scan from `ep`.
pub fn observe<'a>(ep: &'a Episode<'_>) -> CycleInput<'a> {
    let t = ep.sim_time();
    CycleInput {
        stamp_s: t,
        ranges: ep.perception().ranges,
        odom: Odometry {
            pose: ep.believed_pose(),
            vel: ep.state().vel,
            stamp_s: t,
        },
        goal: ep.world().goal,
        global_path: None,
    }
}

/// Simulates one control period with a cycle's decision: a cycle that did not plan holds the
/// last command while the modelled compute runs; a planned `command` is issued at once under
/// the free compute model (`compute_s` is `None`) or after `compute_s` seconds otherwise.
/// Returns the run's status after the period.
pub fn apply(ep: &mut Episode<'_>, command: Twist, planned: bool, compute_s: Option<f64>) -> Status {
    match (planned, compute_s) {
        (false, _) => ep.hold(),
        (true, None) => ep.step(command),
        (true, Some(c)) => ep.step_after(command, c),
    }
}
