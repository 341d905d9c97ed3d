//! Arrival: within `goal_tolerance_m` of the goal the run has arrived; the navigator then
//! commands a stop and says so every cycle until a new goal starts a new run.

use adp_runtime::{sim_robot, CycleInput, Navigator, Odometry, RuntimeOptions, STOP};
use eval::EvalConfig;
use planner::PlannerKind;
use sim::episode::{Episode, Status};
use sim::geometry::{Pose, Vec2};
use sim::robot::Twist;

fn navigator(goal_tolerance_m: f64) -> Navigator {
    let cfg = EvalConfig::load(None).unwrap();
    let options = RuntimeOptions {
        goal_tolerance_m,
        ..RuntimeOptions::new(PlannerKind::Dwa, 1.5)
    };
    Navigator::new(&cfg, options, None).unwrap()
}

fn at<'a>(ranges: &'a [f64], pose: Pose, goal: Vec2, t: f64) -> CycleInput<'a> {
    CycleInput {
        stamp_s: t,
        ranges,
        odom: Odometry {
            pose,
            vel: Twist::new(0.5, 0.0),
            stamp_s: t,
        },
        goal,
        global_path: None,
    }
}

#[test]
fn within_the_tolerance_the_run_arrives_and_stops_until_a_new_goal() {
    let mut nav = navigator(0.3);
    let free = vec![30.0; nav.lidar().angles().len()];
    let goal = Vec2::new(4.0, 0.0);
    let out = nav
        .cycle(&at(&free, Pose::new(0.0, 0.0, 0.0), goal, 0.0))
        .unwrap();
    assert!(!out.arrived && out.planned && out.command.v > 0.0);
    let out = nav
        .cycle(&at(&free, Pose::new(3.75, 0.1, 0.0), goal, 0.05))
        .unwrap();
    assert!(out.arrived && out.planned && !out.agent_step && out.compute_s.is_none());
    assert_eq!(out.command, STOP);
    // Latched: drifting out of the tolerance does not restart the run.
    let out = nav
        .cycle(&at(&free, Pose::new(3.0, 0.0, 0.0), goal, 0.1))
        .unwrap();
    assert!(out.arrived);
    assert_eq!(out.command, STOP);
    // A new goal starts a new run.
    let out = nav
        .cycle(&at(&free, Pose::new(3.0, 0.0, 0.0), Vec2::new(8.0, 0.0), 0.15))
        .unwrap();
    assert!(!out.arrived && out.planned && out.command.v > 0.0);
    // A tolerance that is not a distance is refused.
    let cfg = EvalConfig::load(None).unwrap();
    let bad = RuntimeOptions {
        goal_tolerance_m: -1.0,
        ..RuntimeOptions::new(PlannerKind::Dwa, 1.5)
    };
    let err = Navigator::new(&cfg, bad, None)
        .err()
        .expect("refused")
        .to_string();
    assert_eq!(
        err,
        "runtime configuration: goal_tolerance_m = -1 must be finite and >= 0"
    );
}

#[test]
fn a_robot_driven_to_its_goal_arrives_and_stays_there() {
    // A tolerance wide enough for the robot to brake before BARN's 1 m success radius, so
    // the runtime's arrival comes first and the simulated robot is left standing.
    let mut nav = navigator(2.5);
    let world = &sim::catalog::barn_worlds()[3];
    let mut ep = Episode::new(world, *nav.episode(), 5);
    let mut arrived_at = None;
    for period in 0..2000 {
        let out = nav.cycle(&sim_robot::observe(&ep)).unwrap();
        if out.arrived {
            assert_eq!(out.command, STOP);
            arrived_at.get_or_insert(period);
            if period > arrived_at.unwrap() + 40 {
                break;
            }
        }
        let status = sim_robot::apply(&mut ep, out.command, out.planned, out.compute_s);
        assert_eq!(status, Status::Running, "period {period}");
    }
    assert!(arrived_at.is_some(), "never arrived");
    let d = ep.believed_pose().position().dist(world.goal);
    assert!(d <= 2.5 && d > 1.0, "stopped {d} m from the goal");
    assert!(ep.state().vel.v.abs() < 1e-3, "{:?}", ep.state().vel);
}
