//! Once warm, a control cycle on DDP allocates nothing: the scan's copy, the costmap, the
//! global path, the perception and the planner's buffers are all reused. A policy step also
//! builds its schedule every agent period. The navigator runs inside a rayon pool, as a
//! robot's control thread would: called from outside any pool, MPPI's parallel rollouts are
//! handed to rayon's global pool, whose queue allocates now and then.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use adp_runtime::{load_policy, sim_robot, Navigator, RuntimeOptions};
use eval::EvalConfig;
use planner::PlannerKind;
use sim::episode::{Episode, Status};

/// The system allocator, counting the allocations of each thread while it counts.
struct Counting;

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn count() {
    if COUNTING.with(Cell::get) {
        ALLOCATIONS.with(|a| a.set(a.get() + 1));
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        System.alloc(layout)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `nav.cycle` over periods `warm..warm + n` of world `w`'s episode.
fn allocations(kind: PlannerKind, with_policy: bool, w: usize, warm: usize, n: usize) -> usize {
    let cfg = EvalConfig::load(None).unwrap();
    let policy = with_policy.then(|| {
        load_policy(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/examples/policy"
        )))
        .unwrap()
    });
    // The example policy was trained for DWA; every planner's cycle is counted with it.
    let options = RuntimeOptions {
        allow_policy_mismatch: true,
        ..RuntimeOptions::new(kind, 1.5)
    };
    let mut nav = Navigator::new(&cfg, options, policy).unwrap();
    let world = &sim::catalog::barn_worlds()[w];
    let mut ep = Episode::new(world, *nav.episode(), 1);
    let mut counted = 0;
    for period in 0..warm + n {
        let input = sim_robot::observe(&ep);
        ALLOCATIONS.with(|a| a.set(0));
        COUNTING.with(|c| c.set(period >= warm));
        let out = nav.cycle(&input).unwrap();
        COUNTING.with(|c| c.set(false));
        counted += ALLOCATIONS.with(Cell::get);
        let status = sim_robot::apply(&mut ep, out.command, out.planned, out.compute_s);
        assert_eq!(
            status,
            Status::Running,
            "the episode ended before the counted periods"
        );
    }
    counted
}

/// [`allocations`] on the one thread of a rayon pool.
fn in_pool(kind: PlannerKind, with_policy: bool) -> usize {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    pool.install(|| allocations(kind, with_policy, 3, 40, 60))
}

#[test]
fn a_warm_ddp_cycle_allocates_nothing() {
    for kind in PlannerKind::ALL {
        assert_eq!(in_pool(kind, false), 0, "{}", kind.name());
    }
}

#[test]
fn a_warm_policy_cycle_allocates_only_its_schedule() {
    // 60 periods: 12 agent steps, each building one schedule from the action (its
    // parameters, boundary times, steps and check counts: four small vectors).
    for kind in PlannerKind::ALL {
        let n = in_pool(kind, true);
        assert!(n <= 12 * 4, "{}: {n} allocations in 60 periods", kind.name());
    }
}
