//! No input aborts the runtime and every command stays inside the limits: goals, poses and
//! settings outside the envelope are refused with an error naming the limit (they once
//! aborted the process allocating a costmap of gigabytes), a measured velocity far outside
//! the limits still gets a command inside them from every planner, and NaN or infinite
//! beams read as no return.

mod common;

use common::{input, policy_dir, recorded};

use adp_runtime::{load_policy, CommandLimits, Navigator, Odometry, RuntimeError, RuntimeOptions, STOP};
use eval::EvalConfig;
use planner::PlannerKind;
use sim::geometry::{Pose, Vec2};
use sim::robot::Twist;
use testkit::fresh_dir;

fn navigator(kind: PlannerKind, with_policy: bool, options: RuntimeOptions) -> Navigator {
    let cfg = EvalConfig::load(None).unwrap();
    let policy = with_policy.then(|| load_policy(&policy_dir()).unwrap());
    Navigator::new(
        &cfg,
        RuntimeOptions {
            planner: kind,
            // The example policy was trained for DWA at 1.5 m/s; the envelope holds under any
            // planner and speed it runs with.
            allow_policy_mismatch: true,
            ..options
        },
        policy,
    )
    .unwrap()
}

fn dwa() -> Navigator {
    navigator(PlannerKind::Dwa, true, RuntimeOptions::new(PlannerKind::Dwa, 1.5))
}

#[test]
fn goals_and_poses_outside_the_envelope_are_refused_and_lose_nothing() {
    let inputs = recorded(dwa(), 6);
    let mut clean = dwa();
    let mut faulty = dwa();
    for (k, (ranges, odom, goal)) in inputs.iter().enumerate() {
        let here = odom.pose.position();
        let far = Vec2::new(here.x + 14_000.0, here.y);
        let far_pose = Odometry {
            pose: Pose::new(1e6, odom.pose.y, odom.pose.yaw),
            ..*odom
        };
        let beyond = Vec2::new(1e300, -1e300);
        let faults = [
            (
                input(ranges, *odom, far),
                format!(
                    "goal: ({}, {}) is 14000.0 m from the robot; at most 50 m \
                     (max_goal_distance_m): give a nearer goal, e.g. a waypoint of a global plan",
                    far.x, far.y
                ),
            ),
            (
                input(ranges, far_pose, *goal),
                format!(
                    "goal: ({}, {}) is {:.1} m from the robot; at most 50 m \
                     (max_goal_distance_m): give a nearer goal, e.g. a waypoint of a global plan",
                    goal.x,
                    goal.y,
                    goal.dist(far_pose.pose.position())
                ),
            ),
            (
                input(ranges, *odom, beyond),
                "goal: (1e300, -1e300) is outside the envelope: |x| and |y| at most 1e7 m".to_string(),
            ),
        ];
        for (bad, want) in &faults {
            let err = faulty.cycle(bad).unwrap_err();
            assert!(matches!(err, RuntimeError::Goal(_)), "{err}");
            assert_eq!(err.to_string(), *want, "period {k}");
            assert_eq!(err.command(), STOP);
        }
        let good = input(ranges, *odom, *goal);
        assert_eq!(
            faulty.cycle(&good).unwrap(),
            clean.cycle(&good).unwrap(),
            "period {k}"
        );
    }
}

#[test]
fn a_goal_at_the_envelopes_edge_plans_on_a_bounded_costmap() {
    let (ranges, odom, _) = recorded(dwa(), 1).remove(0);
    let here = odom.pose.position();
    // 50 m away on the diagonal: the largest costmap the default envelope allows.
    let edge = here + Vec2::new(35.3, 35.3);
    let mut nav = dwa();
    let out = nav.cycle(&input(&ranges, odom, edge)).unwrap();
    assert!(nav.limits().contains(out.command));
    let map = nav.nav().unwrap().costmap();
    let cells = (map.nx() * map.ny()) as f64;
    let bound = adp_runtime::envelope::costmap_cells(&nav.episode().costmap, 50.0);
    assert!(
        cells <= bound && bound < 200_000.0,
        "{cells} cells, bound {bound}"
    );
}

#[test]
fn settings_outside_the_envelope_are_refused_naming_the_key() {
    let cfg = EvalConfig::load(None).unwrap();
    let refused = |options: RuntimeOptions| {
        Navigator::new(&cfg, options, None)
            .err()
            .expect("refused")
            .to_string()
    };
    let dwa = RuntimeOptions::new(PlannerKind::Dwa, 1.5);
    assert_eq!(
        refused(RuntimeOptions {
            max_speed: 1e9,
            ..dwa
        }),
        "runtime configuration: max_speed = 1000000000 m/s exceeds the runtime's limit of 5 m/s"
    );
    assert_eq!(
        refused(RuntimeOptions {
            max_speed: 3.0,
            ..dwa
        }),
        "runtime configuration: max_speed = 3 m/s exceeds the robot's [episode.robot] max_v = 2 m/s"
    );
    assert_eq!(
        refused(RuntimeOptions {
            max_goal_distance_m: f64::INFINITY,
            ..dwa
        }),
        "runtime configuration: max_goal_distance_m = inf must be finite and > 0"
    );
    assert!(refused(RuntimeOptions {
        max_goal_distance_m: 1000.0,
        ..dwa
    })
    .contains("allows a costmap of 51165409 cells, over the runtime's limit of 4194304"));

    // The same from a configuration file, which names it; the new keys are read.
    let dir = fresh_dir("runtime-envelope-config");
    std::fs::write(dir.join("fast.toml"), "planner = \"dwa\"\nmax_speed = 1e9\n").unwrap();
    let err = Navigator::from_file(&dir.join("fast.toml"))
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.starts_with(&dir.join("fast.toml").display().to_string()) && err.contains("max_speed"),
        "{err}"
    );
    std::fs::write(
        dir.join("near.toml"),
        "planner = \"dwa\"\nmax_speed = 1.5\nmax_goal_distance_m = 5.0\n",
    )
    .unwrap();
    let mut near = Navigator::from_file(&dir.join("near.toml")).unwrap();
    let (ranges, odom, goal) = recorded(self::dwa(), 1).remove(0);
    let err = near.cycle(&input(&ranges, odom, goal)).unwrap_err().to_string();
    assert!(err.contains("at most 5 m (max_goal_distance_m)"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn every_planner_commands_inside_the_limits_whatever_the_measured_velocity() {
    let inputs = recorded(dwa(), 12);
    let measured = [
        Twist::new(3.0, 0.0),
        Twist::new(10.0, 0.0),
        Twist::new(1e6, 0.0),
        Twist::new(-5.0, 0.0),
        Twist::new(-1e6, 0.0),
        Twist::new(0.5, 50.0),
        Twist::new(0.5, -50.0),
        Twist::new(1e6, 1e6),
        Twist::new(-1e6, -1e6),
    ];
    let want = CommandLimits {
        max_v: 1.5,
        max_reverse_v: 1.5,
        max_w: 4.0,
    };
    for kind in PlannerKind::ALL {
        for with_policy in [false, true] {
            for vel in measured {
                let mut nav = navigator(kind, with_policy, RuntimeOptions::new(kind, 1.5));
                assert_eq!(nav.limits(), want);
                for (k, (ranges, odom, goal)) in inputs.iter().enumerate() {
                    let odom = Odometry { vel, ..*odom };
                    let out = nav.cycle(&input(ranges, odom, *goal)).unwrap();
                    assert!(
                        want.contains(out.command),
                        "{} (policy {with_policy}) measuring {vel:?}, period {k}: {:?}",
                        kind.name(),
                        out.command
                    );
                }
            }
        }
    }
}

#[test]
fn nan_and_infinite_beams_read_as_no_return_unless_turned_off() {
    let inputs = recorded(dwa(), 8);
    let mut with_nan = dwa();
    let mut with_max = dwa();
    let max_range = with_nan.lidar().config().max_range;
    for (k, (ranges, odom, goal)) in inputs.iter().enumerate() {
        let mut faulty = ranges.clone();
        let mut no_return = ranges.clone();
        for (j, bad) in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY]
            .into_iter()
            .enumerate()
        {
            faulty[k * 40 + j * 7] = bad;
            no_return[k * 40 + j * 7] = max_range;
        }
        assert_eq!(
            with_nan.cycle(&input(&faulty, *odom, *goal)).unwrap(),
            with_max.cycle(&input(&no_return, *odom, *goal)).unwrap(),
            "period {k}"
        );
    }
    // Turned off: a NaN range is refused, as before.
    let (ranges, odom, goal) = &inputs[0];
    let mut strict = navigator(
        PlannerKind::Dwa,
        true,
        RuntimeOptions {
            nan_as_no_return: false,
            ..RuntimeOptions::new(PlannerKind::Dwa, 1.5)
        },
    );
    let mut faulty = ranges.clone();
    faulty[9] = f64::NAN;
    assert_eq!(
        strict
            .cycle(&input(&faulty, *odom, *goal))
            .unwrap_err()
            .to_string(),
        "scan: range 9 is NaN (nan_as_no_return = false)"
    );
}
