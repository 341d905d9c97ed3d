//! Planning with a forecast of moving obstacles: a hand-built crossing.
//!
//! The robot drives along +x toward a goal 6 m ahead at 1 m/s in open space. A cylinder of
//! radius 0.3 m crosses its route from the right at 1 m/s, timed to meet it 2.5 m ahead.
//! Each 0.05 s control period the planner sees the cylinder's near half as scan points and,
//! with prediction on, the cylinder's true position and velocity (an oracle forecast: what a
//! perfect tracker would report). The robot moves as the Jackal's limits allow.
//! Without the forecast DWA only avoids where the cylinder is and is hit from the side; with
//! it, DWA keeps clear and still arrives.
//!
//! The standalone system checked only its 2 s horizon against the forecast: it swerved left,
//! the way the cylinder is going (every rollout was clear for 2 s, ending in the cylinder's
//! path), and when the cylinder caught up and no sample was feasible it stopped in its path
//! (clearance -0.51 m). Its rollouts must now also end where the robot could stand clear of
//! the forecast for `moving_hold_time` (1 s) past the horizon: it yields, slowing down
//! behind the cylinder, and drives on once it has passed.

use planner::{Dwa, DwaConfig, NavSystem, PlanInput, Planner, Predicted, Schedule, SystemConfig};
use sim::geometry::{Circle, Footprint, Pose, Vec2};
use sim::robot::{RobotLimits, RobotState, Twist};

/// Smallest footprint clearance to the cylinder over the run (negative: contact), whether
/// the robot got within 0.5 m of the goal, and how far along x it got.
fn drive(planner: &mut dyn Planner, predict: bool) -> (f64, bool, f64) {
    let limits = RobotLimits::JACKAL;
    let fp = Footprint::JACKAL;
    let schedule = Schedule::ddp_default();
    let dt = 0.05;
    let goal = Vec2::new(6.0, 0.0);
    let mut robot = RobotState {
        pose: Pose::default(),
        vel: Twist::new(1.0, 0.0),
    };
    let (start, velocity, radius) = (Vec2::new(2.5, -2.5), Vec2::new(0.0, 1.0), 0.3);
    let mut worst = f64::INFINITY;
    let mut points = Vec::new();
    for k in 0..160 {
        let t = k as f64 * dt;
        let centre = start + velocity * t;
        worst = worst.min(fp.clearance_to_circle(&robot.pose, &Circle { c: centre, r: radius }));
        if robot.pose.position().dist(goal) < 0.5 {
            return (worst, true, robot.pose.x);
        }
        // The near half of the cylinder as scan points, robot frame.
        let local = robot.pose.to_local(centre);
        let toward = local * (-1.0 / local.norm());
        points.clear();
        for i in 0..=12 {
            let a = -std::f64::consts::FRAC_PI_2 + std::f64::consts::PI * i as f64 / 12.0;
            points.push(local + toward.rotated(a) * radius);
        }
        let path = [Vec2::default(), robot.pose.to_local(goal)];
        let moving = [Predicted {
            position: local,
            velocity: velocity.rotated(-robot.pose.yaw),
            radius,
            residual: None,
        }];
        let cmd = planner.plan(&PlanInput {
            perception: sim::Perception {
                ranges: &[],
                points: &points,
                vel: robot.vel,
                local_goal: path[1],
                local_path: &path,
                goal: path[1],
            },
            schedule: &schedule,
            max_speed: 1.0,
            prediction: planner::Prediction::PAPERS,
            budget: planner::Budget::UNLIMITED,
            moving: if predict { &moving } else { &[] },
        });
        robot.step(&limits, cmd, dt);
    }
    (worst, false, robot.pose.x)
}

#[test]
fn dwa_keeps_clear_of_a_crossing_obstacle_only_with_its_forecast() {
    let (blind, ..) = drive(&mut Dwa::new(DwaConfig::default()), false);
    let (seeing, arrived, _) = drive(&mut Dwa::new(DwaConfig::default()), true);
    eprintln!("DWA-DDP, crossing: clearance without forecast {blind:.3} m, with {seeing:.3} m");
    assert!(blind <= 0.0, "without the forecast the crossing hits: {blind}");
    assert!(seeing > 0.0, "with the forecast it keeps clear: {seeing}");
    assert!(arrived, "and still reaches the goal");
}

#[test]
fn the_system_yields_to_a_crossing_obstacle_with_its_forecast() {
    let (blind, ..) = drive(&mut NavSystem::new(SystemConfig::default(), 1), false);
    let (seeing, _, x) = drive(&mut NavSystem::new(SystemConfig::default(), 1), true);
    eprintln!("system-DDP, crossing: clearance without forecast {blind:.3} m, with {seeing:.3} m, reached x = {x:.2} m");
    assert!(blind <= 0.0, "without the forecast the crossing hits: {blind}");
    assert!(seeing > 0.1, "with the forecast it keeps clear: {seeing}");
    // It drives on past the crossing (in low-speed mode, which it entered while yielding).
    assert!(x > 3.5, "and gets past the crossing: x = {x}");
}
