//! A schedule given from outside ([`Navigator::set_schedule`]), as a training actor whose
//! learner's policy chooses it: the planner runs on it exactly as on the same schedule fixed
//! by the configuration, it holds until changed, it is refused beside the navigator's own
//! policy and outside the envelope, and the local goal a policy's observation reads is there.

use std::path::Path;

use adp_runtime::{
    load_policy, sim_robot, CycleOutput, FixedSchedule, Navigator, RuntimeError, RuntimeOptions,
};
use eval::EvalConfig;
use planner::{PlannerKind, Schedule};
use sim::episode::{Episode, Status};

fn navigator(fixed: FixedSchedule) -> Navigator {
    let cfg = EvalConfig::load(None).unwrap();
    let mut options = RuntimeOptions::new(PlannerKind::Dwa, 1.5);
    options.fixed = fixed;
    Navigator::new(&cfg, options, None).unwrap()
}

/// Drives BARN world `world` with `nav`, calling `each` before every cycle; returns every
/// cycle's output and the final status.
fn drive(
    nav: &mut Navigator,
    world: usize,
    mut each: impl FnMut(&mut Navigator, usize),
) -> (Vec<CycleOutput>, Status) {
    let w = sim::catalog::world(world).unwrap();
    let mut ep = Episode::new(w, *nav.episode(), 3);
    let mut outs = Vec::new();
    for k in 0..3000 {
        each(nav, k);
        let out = nav.cycle(&sim_robot::observe(&ep)).unwrap();
        let status = sim_robot::apply(&mut ep, out.command, out.planned, out.compute_s);
        outs.push(out);
        if status != Status::Running {
            return (outs, status);
        }
    }
    (outs, Status::Running)
}

#[test]
fn a_given_schedule_plans_as_the_same_fixed_one() {
    let (fixed, status) = drive(&mut navigator(FixedSchedule::Vanilla), 3, |_, _| {});
    assert_eq!(status, Status::Succeeded);
    let mut given = navigator(FixedSchedule::Ddp);
    given.set_schedule(Schedule::vanilla()).unwrap();
    let (outs, status_given) = drive(&mut given, 3, |_, _| {});
    assert_eq!(status_given, status);
    assert_eq!(outs, fixed, "the same schedule, the same run, bit for bit");
}

#[test]
fn a_schedule_holds_until_the_next_call() {
    // Vanilla for the first 20 cycles, then DDP: the first 20 outputs are vanilla's run's,
    // and from cycle 20 on the schedule in force is DDP's.
    let (vanilla, _) = drive(&mut navigator(FixedSchedule::Vanilla), 3, |_, _| {});
    let mut nav = navigator(FixedSchedule::Ddp);
    let (outs, status) = drive(&mut nav, 3, |nav, k| match k {
        0 => nav.set_schedule(Schedule::vanilla()).unwrap(),
        20 => nav.set_schedule(Schedule::ddp_default()).unwrap(),
        _ => {}
    });
    assert_eq!(status, Status::Succeeded);
    assert_eq!(outs[..20], vanilla[..20]);
    let ddp = Schedule::ddp_default();
    let planned_ddp = outs[20..].iter().find_map(|o| o.schedule).unwrap();
    assert_eq!(planned_ddp.steps, ddp.len());
    assert!((planned_ddp.horizon_s - ddp.horizon()).abs() < 1e-12);
}

#[test]
fn refused_beside_a_policy_and_outside_the_envelope() {
    let cfg = EvalConfig::load(None).unwrap();
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/policy"));
    let policy = load_policy(dir).unwrap();
    let mut with_policy =
        Navigator::new(&cfg, RuntimeOptions::new(PlannerKind::Dwa, 1.5), Some(policy)).unwrap();
    let err = with_policy.set_schedule(Schedule::vanilla()).unwrap_err();
    assert!(matches!(err, RuntimeError::Config { .. }));
    assert!(
        err.to_string()
            .contains("the navigator's policy chooses the schedules"),
        "{err}"
    );

    let mut nav = navigator(FixedSchedule::Vanilla);
    let long = Schedule::uniform(0.1, 65, 20).unwrap();
    let err = nav.set_schedule(long).unwrap_err().to_string();
    assert!(err.contains("65 steps: at most 64"), "{err}");
    let far = Schedule::uniform(0.5, 20, 20).unwrap();
    let err = nav.set_schedule(far).unwrap_err().to_string();
    assert!(err.contains("10 s horizon: at most 5 s"), "{err}");
    // A refusal changes nothing: the run is vanilla's.
    let (outs, _) = drive(&mut nav, 3, |_, _| {});
    let (vanilla, _) = drive(&mut navigator(FixedSchedule::Vanilla), 3, |_, _| {});
    assert_eq!(outs, vanilla);
}

#[test]
fn the_local_goal_is_ahead_on_the_path() {
    let mut nav = navigator(FixedSchedule::Ddp);
    assert!(nav.local_goal().is_none());
    let w = sim::catalog::world(3).unwrap();
    let ep = Episode::new(w, *nav.episode(), 3);
    nav.cycle(&sim_robot::observe(&ep)).unwrap();
    let g = nav.local_goal().unwrap();
    let start = w.start.position();
    // Towards the goal (+y from the start corridor), within the costmap's reach.
    assert!(
        g.y > start.y && g.dist(start) < 10.0,
        "local goal {g:?} from {start:?}"
    );
}
