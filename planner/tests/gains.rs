//! Objective gains: factors of 1 are the configured planner bit for bit, and a changed gain
//! moves the behaviour the way its term says (a heavier obstacle term keeps the robot farther
//! from the posts it passes).

mod common;

use planner::run::run_episode;
use planner::{
    Dwa, DwaConfig, Gains, LogMppi, LogMppiConfig, Mppi, MppiConfig, NavSystem, Planner, Schedule,
    SystemConfig,
};
use sim::{Circle, EpisodeConfig, Vec2, World};

fn planners() -> [Box<dyn Planner>; 3] {
    [
        Box::new(Dwa::new(DwaConfig::default())),
        Box::new(Mppi::new(MppiConfig::default(), 3)),
        Box::new(NavSystem::new(SystemConfig::default(), 3)),
    ]
}

/// The exact bits of every pose and command of a DDP episode on `world`, and the smallest
/// distance between the robot's centre and the surface of the world's last cylinder (the post
/// the scenes add). With `factors`, they are set before every planning cycle.
fn drive(planner: &mut dyn Planner, world: &World, factors: Option<&[f64]>) -> (Vec<u64>, f64) {
    let mut bits = Vec::new();
    let mut closest = f64::INFINITY;
    if let Some(f) = factors {
        planner.set_gain_factors(f).unwrap();
    }
    let (result, _) = run_episode(
        world,
        EpisodeConfig::default(),
        planner,
        &Schedule::ddp_default(),
        1.5,
        7,
        None,
        |ep, p, cmd| {
            let s = ep.state();
            bits.extend([s.pose.x, s.pose.y, s.pose.yaw, cmd.v, cmd.w].map(f64::to_bits));
            let post = world.cylinders.last().expect("a scene with a post");
            closest = closest.min(Vec2::new(s.pose.x, s.pose.y).dist(post.c) - post.r);
            if let Some(f) = factors {
                p.set_gain_factors(f).unwrap();
            }
        },
    );
    bits.extend([result.time_s, result.distance_m].map(f64::to_bits));
    (bits, closest)
}

#[test]
fn factors_of_one_reproduce_the_configured_planner_bit_for_bit() {
    let world = common::weaving_corridor();
    for (mut plain, mut gained) in planners().into_iter().zip(planners()) {
        let g = gained.gains().expect("these planners have gains");
        // Another setting first: going back to factors of 1 restores the configured weights.
        gained.set_gain_factors(&vec![2.0; g.len()]).unwrap();
        let (want, _) = drive(plain.as_mut(), &world, None);
        let (got, _) = drive(gained.as_mut(), &world, Some(&vec![1.0; g.len()]));
        assert_eq!(got, want, "{}", plain.name());
    }
}

#[test]
fn a_heavier_obstacle_term_keeps_a_larger_clearance() {
    // A post of radius 0.2 m 3 m ahead, 0.1 m left of the straight line to the goal, in a
    // corridor 4 m wide (its walls far from the post).
    let world = World::corridor(
        2.0,
        &[Circle {
            c: Vec2::new(-0.1, 3.0),
            r: 0.2,
        }],
    );
    for gains in Gains::ALL {
        let k = gains.names().iter().position(|n| n.contains("obstacle")).unwrap();
        let clearance = |factor: f64| {
            let mut p = planners().into_iter().find(|p| p.gains() == Some(gains)).unwrap();
            let mut f = vec![1.0; gains.len()];
            f[k] = factor;
            drive(p.as_mut(), &world, Some(&f)).1
        };
        let (light, tuned, heavy) = (clearance(0.25), clearance(1.0), clearance(2.0));
        assert!(
            light < tuned && tuned < heavy,
            "{}: clearance {light} m with a quarter of the obstacle weight, {tuned} m with the \
             hand-tuned one, {heavy} m with it doubled",
            gains.planner()
        );
    }
}

#[test]
fn planners_without_gains_and_bad_factors_are_refused() {
    let mut log = LogMppi::new(LogMppiConfig::default(), 3);
    assert_eq!(log.gains(), None);
    let e = log.set_gain_factors(&[1.0]).unwrap_err();
    assert!(
        e.to_string()
            .starts_with("planner `log-mppi` has no objective gains"),
        "{e}"
    );
    let mut dwa = Dwa::new(DwaConfig::default());
    let e = dwa.set_gain_factors(&[1.0, f64::NAN, 1.0, 1.0]).unwrap_err();
    assert_eq!(
        e.to_string(),
        "dwa gain factor w_path = NaN: must be finite and >= 0"
    );
    assert!(dwa.set_gain_factors(&[1.0; 3]).is_err());
}
