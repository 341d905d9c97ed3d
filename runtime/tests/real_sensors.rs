//! Real sensors: a lidar of any beam count and field of view, given in the runtime's own
//! configuration, drives a world as `adp eval` drives it with that lidar (the policy's
//! observation resampled from it); a laser mounted off the base origin is re-projected to
//! it, so the costmap marks what the laser sees where it is; odometry stamped after the scan
//! is refused.

use std::path::PathBuf;

use actor::closed_loop::planner_seed;
use adp_runtime::{load_policy, sim_robot, CycleInput, Navigator, Odometry, RuntimeOptions};
use eval::evaluate::{run, run_seed, AdpSetting, EvalPlan, Fidelity, LidarOverride, ObstaclePrediction};
use eval::EvalConfig;
use planner::PlannerKind;
use sim::costmap::OBSTACLE;
use sim::episode::{Episode, Status};
use sim::geometry::{Pose, Vec2};
use sim::robot::Twist;
use testkit::fresh_dir;

const WORLD: usize = 150;

/// The example policy shipped with the crate (DWA at 1.5 m/s).
fn policy_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/policy")
}
const SEED: u64 = 7;

#[test]
fn a_lidar_of_another_beam_count_and_field_drives_as_eval_drives_it() {
    let dir = fresh_dir("runtime-lidar");
    let seed = run_seed(SEED, WORLD, 0);
    // A UST-10LX's beam count, over a narrower field than the policy was trained on.
    std::fs::write(
        dir.join("runtime.toml"),
        format!(
            "planner = \"dwa\"\nmax_speed = 1.5\npolicy = \"{}\"\nseed = {}\n\n\
             [lidar]\nbeams = 1081\nfov_deg = 240.0\nmax_range = 25.0\n",
            policy_dir().display(),
            planner_seed(seed)
        ),
    )
    .unwrap();
    let mut nav = Navigator::from_file(&dir.join("runtime.toml")).unwrap();
    assert_eq!(nav.lidar().angles().len(), 1081);
    let world = &sim::catalog::barn_worlds()[WORLD];
    let mut ep = Episode::new(world, *nav.episode(), seed);
    let mut periods = 0;
    let got = loop {
        let input = sim_robot::observe(&ep);
        assert_eq!(input.ranges.len(), 1081);
        let out = nav.cycle(&input).unwrap();
        periods += 1;
        if sim_robot::apply(&mut ep, out.command, out.planned, out.compute_s) != Status::Running {
            break ep.result();
        }
    };
    assert!(periods > 20, "the run ended after {periods} periods");
    // `adp eval` with the same lidar and policy.
    let mut cfg = EvalConfig::load(None).unwrap();
    cfg.episode.lidar.beams = 1081;
    cfg.episode.lidar.fov_deg = 240.0;
    cfg.episode.lidar.max_range = 25.0;
    let policy = load_policy(&policy_dir()).unwrap();
    let plan = EvalPlan {
        planners: vec![PlannerKind::Dwa],
        fidelities: vec![Fidelity::Adp],
        speeds: vec![1.5],
        worlds: vec![WORLD],
        runs: 1,
        trim: 0,
        seed: SEED,
        adp: AdpSetting {
            space: policy.space,
            action: policy.space.ddp_action(),
        },
        policy_env: policy.env,
        policy: Some(policy.net),
        predictions: vec![ObstaclePrediction::Off],
        lidars: vec![LidarOverride::default()],
    };
    let rows = run(&plan, &cfg, sim::catalog::barn_worlds()).unwrap();
    assert_eq!(got, rows[0].per_world[0].runs[0]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The ranges a laser at `mount` (base frame) of a robot at the origin facing +x measures to
/// the wall x = `wall`.
fn wall_scan(nav: &Navigator, mount: Pose, wall: f64) -> Vec<f64> {
    let max = nav.lidar().config().max_range;
    nav.lidar()
        .angles()
        .iter()
        .map(|a| {
            let dir = (mount.yaw + a).cos();
            let t = (wall - mount.x) / dir;
            if dir > 0.0 && t < max {
                t
            } else {
                max
            }
        })
        .collect()
}

fn cycle_input(ranges: &[f64]) -> CycleInput<'_> {
    CycleInput {
        stamp_s: 1.0,
        ranges,
        odom: Odometry {
            pose: Pose::new(0.0, 0.0, 0.0),
            vel: Twist::default(),
            stamp_s: 1.0,
        },
        goal: Vec2::new(5.0, 5.0),
        global_path: None,
    }
}

/// Whether the costmap marks the cell holding `p` as an obstacle.
fn obstacle_at(nav: &Navigator, p: Vec2) -> bool {
    let map = nav.nav().unwrap().costmap();
    let (ix, iy) = map.cell_of(p).unwrap();
    map.cost(ix, iy) == OBSTACLE
}

#[test]
fn a_laser_mounted_off_the_base_marks_the_wall_where_it_is() {
    let cfg = EvalConfig::load(None).unwrap();
    let mount = Pose::new(0.5, 0.0, 0.0);
    let mounted = RuntimeOptions {
        laser_pose: mount,
        ..RuntimeOptions::new(PlannerKind::Dwa, 1.5)
    };
    let mut nav = Navigator::new(&cfg, mounted, None).unwrap();
    // The wall is 2 m ahead of the base, 1.5 m ahead of the laser.
    let scan = wall_scan(&nav, mount, 2.0);
    nav.cycle(&cycle_input(&scan)).unwrap();
    assert!(obstacle_at(&nav, Vec2::new(2.0, 0.0)));
    assert!(obstacle_at(&nav, Vec2::new(2.0, 1.0)));
    assert!(!obstacle_at(&nav, Vec2::new(1.5, 0.0)));
    // Read as if the laser were at the base origin (today's reading), the wall would be
    // 0.5 m nearer than it is.
    let mut naive = Navigator::new(&cfg, RuntimeOptions::new(PlannerKind::Dwa, 1.5), None).unwrap();
    naive.cycle(&cycle_input(&scan)).unwrap();
    assert!(obstacle_at(&naive, Vec2::new(1.5, 0.0)));
    // A mount off the robot is refused, naming the keys.
    let far = RuntimeOptions {
        laser_pose: Pose::new(8.0, 0.0, 0.0),
        ..RuntimeOptions::new(PlannerKind::Dwa, 1.5)
    };
    let err = Navigator::new(&cfg, far, None)
        .err()
        .expect("refused")
        .to_string();
    assert_eq!(
        err,
        "runtime configuration: [lidar] x = 8, y = 0: the laser's mount must be within 5 m of \
         the base origin"
    );
}

#[test]
fn the_mount_is_read_from_the_lidar_table_and_future_odometry_is_refused() {
    let dir = fresh_dir("runtime-mount");
    std::fs::write(
        dir.join("runtime.toml"),
        "planner = \"dwa\"\nmax_speed = 1.5\n\n[lidar]\nx = 0.5\nyaw_deg = 0.0\n",
    )
    .unwrap();
    let mut nav = Navigator::from_file(&dir.join("runtime.toml")).unwrap();
    let scan = wall_scan(&nav, Pose::new(0.5, 0.0, 0.0), 2.0);
    nav.cycle(&cycle_input(&scan)).unwrap();
    assert!(obstacle_at(&nav, Vec2::new(2.0, 0.0)) && !obstacle_at(&nav, Vec2::new(1.5, 0.0)));
    std::fs::write(
        dir.join("bad.toml"),
        "planner = \"dwa\"\nmax_speed = 1.5\n\n[lidar]\nz = 0.5\n",
    )
    .unwrap();
    let err = Navigator::from_file(&dir.join("bad.toml"))
        .err()
        .expect("refused")
        .to_string();
    assert!(err.contains("unknown field `z`"), "{err}");
    // Odometry stamped 0.5 s after the scan: the clocks disagree; refused, changing nothing.
    let future = CycleInput {
        odom: Odometry {
            stamp_s: 1.5,
            ..cycle_input(&scan).odom
        },
        ..cycle_input(&scan)
    };
    let err = nav.cycle(&future).unwrap_err().to_string();
    assert_eq!(
        err,
        "odometry: stamped 0.500 s after the scan; at most 0.1 s (max_odometry_lead_s): the \
         scan's and the odometry's clocks disagree"
    );
    // A little newer than the scan is usual (odometry comes more often): accepted.
    let newer = CycleInput {
        odom: Odometry {
            stamp_s: 1.04,
            ..cycle_input(&scan).odom
        },
        ..cycle_input(&scan)
    };
    assert!(nav.cycle(&newer).is_ok());
    let _ = std::fs::remove_dir_all(&dir);
}
