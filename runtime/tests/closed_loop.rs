//! The runtime drives a simulated world exactly as `adp eval` does: for each planner, with
//! DDP and with a trained policy, the episode driven through [`Navigator::cycle`] (the
//! simulator only moves the robot and scans) ends bit for bit as `adp eval`'s run of the
//! same world and seed.

use std::path::Path;

use actor::closed_loop::planner_seed;
use actor::EnvConfig;
use adp_runtime::{load_policy, sim_robot, Navigator, RuntimeOptions};
use eval::evaluate::{run, run_seed, AdpSetting, EvalPlan, Fidelity, LidarOverride, ObstaclePrediction};
use eval::EvalConfig;
use planner::{ActionSpace, PlannerKind};
use sim::episode::{Episode, EpisodeResult, Status};
use sim::World;

const SPEED: f64 = 1.5;
const SEED: u64 = 7;
/// Worlds of different clutter (easy, middling, hard) from the test split's range.
const WORLDS: [usize; 3] = [3, 150, 280];

fn policy_dir() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/policy"))
}

/// Drives `world` with `nav`: every control period the navigator gets the episode's scan,
/// believed pose and measured velocity, and the episode applies its command (or holds while
/// its modelled compute runs).
fn drive(nav: &mut Navigator, world: &World, seed: u64) -> EpisodeResult {
    let mut ep = Episode::new(world, *nav.episode(), seed);
    loop {
        let out = nav.cycle(&sim_robot::observe(&ep)).unwrap();
        if sim_robot::apply(&mut ep, out.command, out.planned, out.compute_s) != Status::Running {
            return ep.result();
        }
    }
}

/// `adp eval`'s runs of `WORLDS` (one run each) for `planner` at `fidelity`, with the policy
/// of [`policy_dir`] for `Fidelity::Adp`.
fn evaluated(cfg: &EvalConfig, planner: PlannerKind, fidelity: Fidelity) -> Vec<EpisodeResult> {
    let learned = (fidelity == Fidelity::Adp).then(|| load_policy(policy_dir()).unwrap());
    let space = learned.as_ref().map_or(ActionSpace::Decremental, |p| p.space);
    let plan = EvalPlan {
        planners: vec![planner],
        fidelities: vec![fidelity],
        speeds: vec![SPEED],
        worlds: WORLDS.to_vec(),
        runs: 1,
        trim: 0,
        seed: SEED,
        adp: AdpSetting {
            space,
            action: space.ddp_action(),
        },
        policy_env: learned.as_ref().map_or(EnvConfig::default(), |p| p.env),
        policy: learned.map(|p| p.net),
        predictions: vec![ObstaclePrediction::Off],
        lidars: vec![LidarOverride::default()],
    };
    let rows = run(&plan, cfg, sim::catalog::barn_worlds()).unwrap();
    assert_eq!(rows.len(), 1);
    rows[0].per_world.iter().map(|w| w.runs[0]).collect()
}

fn check(planner: PlannerKind, fidelity: Fidelity) {
    let cfg = EvalConfig::load(None).unwrap();
    let want = evaluated(&cfg, planner, fidelity);
    for (&w, want) in WORLDS.iter().zip(&want) {
        let seed = run_seed(SEED, w, 0);
        let options = RuntimeOptions {
            seed: planner_seed(seed),
            // The example policy was trained for DWA; `adp eval` runs it with any planner,
            // and so does this comparison.
            allow_policy_mismatch: planner != PlannerKind::Dwa,
            ..RuntimeOptions::new(planner, SPEED)
        };
        let policy = (fidelity == Fidelity::Adp).then(|| load_policy(policy_dir()).unwrap());
        let mut nav = Navigator::new(&cfg, options, policy).unwrap();
        let world = &sim::catalog::barn_worlds()[w];
        let got = drive(&mut nav, world, seed);
        assert_eq!(
            &got,
            want,
            "{} {fidelity:?} on world {w}: the runtime's episode differs from adp eval's",
            planner.name()
        );
    }
}

#[test]
fn dwa_ddp_matches_eval() {
    check(PlannerKind::Dwa, Fidelity::Ddp);
}

#[test]
fn mppi_ddp_matches_eval() {
    check(PlannerKind::Mppi, Fidelity::Ddp);
}

#[test]
fn log_mppi_ddp_matches_eval() {
    check(PlannerKind::LogMppi, Fidelity::Ddp);
}

#[test]
fn system_ddp_matches_eval() {
    check(PlannerKind::System, Fidelity::Ddp);
}

#[test]
fn dwa_policy_matches_eval() {
    check(PlannerKind::Dwa, Fidelity::Adp);
}

#[test]
fn mppi_policy_matches_eval() {
    check(PlannerKind::Mppi, Fidelity::Adp);
}

#[test]
fn log_mppi_policy_matches_eval() {
    check(PlannerKind::LogMppi, Fidelity::Adp);
}

#[test]
fn system_policy_matches_eval() {
    check(PlannerKind::System, Fidelity::Adp);
}
