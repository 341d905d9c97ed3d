//! Bad input gets an error that names the fault and the stop command, and loses nothing: a
//! refused cycle leaves the navigator as it was, so the next good cycle is the one a
//! navigator that never saw the bad input would run.

mod common;

use common::{input, policy_dir, recorded};

use adp_runtime::{load_policy, CycleInput, Navigator, Odometry, RuntimeError, RuntimeOptions, STOP};
use eval::EvalConfig;
use planner::PlannerKind;
use sim::geometry::Vec2;
use sim::robot::Twist;
use testkit::fresh_dir;

fn navigator() -> Navigator {
    let cfg = EvalConfig::load(None).unwrap();
    let policy = load_policy(&policy_dir()).unwrap();
    Navigator::new(&cfg, RuntimeOptions::new(PlannerKind::Dwa, 1.5), Some(policy)).unwrap()
}

#[test]
fn each_bad_input_is_refused_with_a_stop_and_loses_nothing() {
    let recorded = recorded(navigator(), 12);
    let mut clean = navigator();
    let mut faulty = navigator();
    for (k, (ranges, odom, goal)) in recorded.iter().enumerate() {
        // Every period, each kind of fault first (each refused), then the good input: the
        // faulty navigator must answer it as the clean one does.
        let far_goal = Vec2::new(goal.x + 14_000.0, goal.y);
        let short_scan = &ranges[1..];
        let stale = Odometry {
            stamp_s: odom.stamp_s - 0.5,
            ..*odom
        };
        let nan_goal = Vec2::new(f64::NAN, goal.y);
        let empty: &[Vec2] = &[];
        let faults: [(CycleInput<'_>, String); 5] = [
            (
                input(ranges, *odom, far_goal),
                format!(
                    "goal: ({}, {}) is {:.1} m from the robot; at most 50 m (max_goal_distance_m): \
                     give a nearer goal, e.g. a waypoint of a global plan",
                    far_goal.x,
                    far_goal.y,
                    far_goal.dist(odom.pose.position())
                ),
            ),
            (
                input(short_scan, *odom, *goal),
                format!(
                    "scan: {} ranges, but the configured lidar has {} beams ([lidar] beams)",
                    ranges.len() - 1,
                    ranges.len()
                ),
            ),
            (
                CycleInput {
                    odom: stale,
                    ..input(ranges, *odom, *goal)
                },
                "odometry: 0.500 s older than the scan; at most 0.1 s (max_odometry_age_s)".into(),
            ),
            (
                input(ranges, *odom, nan_goal),
                format!("goal: (NaN, {}) is not finite", goal.y),
            ),
            (
                CycleInput {
                    global_path: Some(empty),
                    ..input(ranges, *odom, *goal)
                },
                "global path: empty (pass None to plan it)".into(),
            ),
        ];
        for (bad, want) in &faults {
            let err = faulty.cycle(bad).unwrap_err();
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
    assert_eq!(STOP, Twist::new(0.0, 0.0));
}

#[test]
fn exports_that_do_not_fit_are_refused_naming_the_file() {
    let dir = fresh_dir("runtime-bad-export");
    let card: serde_json::Value =
        serde_json::from_slice(&std::fs::read(policy_dir().join("policy.json")).unwrap()).unwrap();
    // A card whose network reads 700 values where the observation has 730.
    let mut narrow = card.clone();
    narrow["network"]["layer_sizes"][0] = 700.into();
    std::fs::write(dir.join("policy.json"), serde_json::to_vec(&narrow).unwrap()).unwrap();
    std::fs::copy(
        policy_dir().join("policy.safetensors"),
        dir.join("policy.safetensors"),
    )
    .unwrap();
    let err = load_policy(&dir).unwrap_err().to_string();
    assert!(
        err.contains("policy.json") && err.contains("layer_sizes [700, 512, 512, 4]"),
        "{err}"
    );
    // The weights missing.
    std::fs::write(dir.join("policy.json"), serde_json::to_vec(&card).unwrap()).unwrap();
    std::fs::remove_file(dir.join("policy.safetensors")).unwrap();
    let err = load_policy(&dir).unwrap_err().to_string();
    assert!(err.contains("policy.safetensors"), "{err}");
    // A policy that observes tracked obstacles needs the tracker, which the runtime lacks.
    let mut tracking = load_policy(&policy_dir()).unwrap();
    tracking.env.observe_tracks = 2;
    let cfg = EvalConfig::load(None).unwrap();
    let err = Navigator::new(&cfg, RuntimeOptions::new(PlannerKind::Dwa, 1.5), Some(tracking))
        .err()
        .expect("refused");
    assert!(matches!(err, RuntimeError::Policy(_)), "{err}");
    assert!(
        err.to_string().contains("does not run the obstacle tracker"),
        "{err}"
    );
    // A speed cap that is not positive.
    let err = Navigator::new(&cfg, RuntimeOptions::new(PlannerKind::Dwa, 0.0), None)
        .err()
        .expect("refused");
    assert_eq!(
        err.to_string(),
        "runtime configuration: max_speed = 0 must be finite and > 0"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_configuration_file_builds_a_navigator_and_bad_keys_are_named() {
    let dir = fresh_dir("runtime-config");
    let policy = policy_dir();
    let good = format!(
        "planner = \"mppi\"\nmax_speed = 2.0\npolicy = \"{}\"\nseed = 4\n\
         allow_policy_mismatch = true\n",
        policy.display()
    );
    std::fs::write(dir.join("runtime.toml"), good).unwrap();
    let nav = Navigator::from_file(&dir.join("runtime.toml")).unwrap();
    assert_eq!(nav.planner(), PlannerKind::Mppi);
    assert_eq!(nav.space(), Some(planner::ActionSpace::Decremental));
    std::fs::write(
        dir.join("bad.toml"),
        "planner = \"dwa\"\nmax_speed = 1.5\nspeed = 3\n",
    )
    .unwrap();
    let err = Navigator::from_file(&dir.join("bad.toml"))
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.starts_with(&dir.join("bad.toml").display().to_string()),
        "{err}"
    );
    assert!(err.contains("unknown field `speed`"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_new_goal_starts_a_new_run() {
    let recorded = recorded(navigator(), 3);
    let mut nav = navigator();
    let (ranges, odom, goal) = &recorded[0];
    let first = nav.cycle(&input(ranges, *odom, *goal)).unwrap();
    nav.cycle(&input(&recorded[1].0, recorded[1].1, *goal)).unwrap();
    // Back to the first inputs with the goal moved and back: a fresh run each time, so the
    // same inputs give the first answer again.
    let moved = Vec2::new(goal.x + 1.0, goal.y);
    let other = nav.cycle(&input(ranges, *odom, moved)).unwrap();
    assert!(other.agent_step);
    assert_eq!(nav.nav().unwrap().goal(), moved);
    assert_eq!(nav.cycle(&input(ranges, *odom, *goal)).unwrap(), first);
}

#[test]
fn a_policy_trained_for_another_planner_or_speed_is_refused_naming_both() {
    let cfg = EvalConfig::load(None).unwrap();
    let card = policy_dir().join("policy.json");
    let refused = |options: RuntimeOptions, policy| {
        Navigator::new(&cfg, options, Some(policy))
            .err()
            .expect("refused")
            .to_string()
    };
    let allow = "(allow_policy_mismatch = true runs it anyway, for a transfer experiment)";
    // The example policy was trained for DWA at 1.5 m/s.
    assert_eq!(
        refused(
            RuntimeOptions::new(PlannerKind::Mppi, 1.5),
            load_policy(&policy_dir()).unwrap()
        ),
        format!(
            "policy {}: trained for dwa at max_speed = 1.5 m/s, but the runtime runs mppi at \
             max_speed = 1.5 m/s: run the planner and speed it was trained for {allow}",
            card.display()
        )
    );
    let err = refused(
        RuntimeOptions::new(PlannerKind::Dwa, 2.0),
        load_policy(&policy_dir()).unwrap(),
    );
    assert!(
        err.contains("trained for dwa at max_speed = 1.5 m/s, but the runtime runs dwa at max_speed = 2 m/s"),
        "{err}"
    );
    // A card from before the planner was recorded: refused, with the way to re-export it.
    let mut old = load_policy(&policy_dir()).unwrap();
    old.card.trained_for = None;
    let err = refused(RuntimeOptions::new(PlannerKind::Dwa, 1.5), old);
    assert!(
        err.contains("does not record the planner and speed it was trained for")
            && err.contains("adp export --planner P --max-speed S")
            && err.contains("runtime's dwa at max_speed = 1.5 m/s"),
        "{err}"
    );
    // Allowed for a transfer experiment; the matching runtime needs no allowance.
    let transfer = RuntimeOptions {
        allow_policy_mismatch: true,
        ..RuntimeOptions::new(PlannerKind::Mppi, 1.5)
    };
    let nav = Navigator::new(&cfg, transfer, Some(load_policy(&policy_dir()).unwrap())).unwrap();
    assert_eq!(nav.planner(), PlannerKind::Mppi);
    assert!(Navigator::new(
        &cfg,
        RuntimeOptions::new(PlannerKind::Dwa, 1.5),
        Some(load_policy(&policy_dir()).unwrap())
    )
    .is_ok());
    // Through a configuration file: the same refusal, and the key that allows it.
    let dir = fresh_dir("runtime-trained-for");
    let body = format!(
        "planner = \"system\"\nmax_speed = 1.5\npolicy = \"{}\"\n",
        policy_dir().display()
    );
    std::fs::write(dir.join("system.toml"), &body).unwrap();
    let err = Navigator::from_file(&dir.join("system.toml"))
        .err()
        .expect("refused")
        .to_string();
    assert!(
        err.contains("but the runtime runs system at max_speed = 1.5 m/s"),
        "{err}"
    );
    std::fs::write(dir.join("allowed.toml"), body + "allow_policy_mismatch = true\n").unwrap();
    assert!(Navigator::from_file(&dir.join("allowed.toml")).is_ok());
    let _ = std::fs::remove_dir_all(&dir);
}
