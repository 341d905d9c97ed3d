//! Planning cycles do not allocate: a planner's buffers grow to the largest scan and sample set
//! they have met and are reused from then on, so a planner that has driven an episode drives it
//! again without one allocation. A counting global allocator counts the allocations made while
//! a planning call runs (on any thread: MPPI, Log-MPPI and the system evaluate samples on
//! rayon's workers). A `Vec` built per cycle, a `collect` or a clone in a cycle fails here.
//! Planners with objective gains also take their gain factors inside the counted region before
//! every cycle, as the objective-weight action spaces set them.
//!
//! This file holds one test, so no other test's thread allocates while the counter is armed.

mod common;

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use planner::compute::ComputeConfig;
use planner::run::run_episode;
use planner::{
    Dwa, DwaConfig, LogMppi, LogMppiConfig, Mppi, MppiConfig, NavSystem, PlanInput, Planner, Schedule,
    SystemConfig, Trace,
};
use sim::robot::Twist;
use sim::EpisodeConfig;

/// The system allocator, counting `alloc` and `realloc` calls while [`ARMED`] is set.
struct Counting;

static ARMED: AtomicBool = AtomicBool::new(false);
static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

// SAFETY: every call is forwarded unchanged to the system allocator; the counter is a side
// effect only.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if ARMED.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: forwarded with the caller's layout.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if ARMED.load(Ordering::Relaxed) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: forwarded unchanged.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Arms the counter around every planning call once `armed` is set (the second episode).
struct Counted<'a> {
    inner: &'a mut dyn Planner,
    armed: bool,
    calls: u32,
    /// (call index, allocations) of every counted call that allocated.
    allocating: Vec<(u32, u64)>,
    counted: u32,
}

impl Planner for Counted<'_> {
    fn name(&self) -> &'static str {
        self.inner.name()
    }

    fn plan(&mut self, input: &PlanInput<'_>) -> Twist {
        self.calls += 1;
        if !self.armed {
            return self.inner.plan(input);
        }
        // Factors of 1: the same episode as the uncounted one, so the buffers fit it.
        let ones = [1.0; 8];
        let gains = self.inner.gains().map_or(0, |g| g.len());
        let before = ALLOCATIONS.load(Ordering::SeqCst);
        ARMED.store(true, Ordering::SeqCst);
        if gains > 0 {
            self.inner
                .set_gain_factors(&ones[..gains])
                .expect("the planner's own gain count");
        }
        let cmd = self.inner.plan(input);
        ARMED.store(false, Ordering::SeqCst);
        let made = ALLOCATIONS.load(Ordering::SeqCst) - before;
        self.counted += 1;
        if made > 0 {
            self.allocating.push((self.calls, made));
        }
        cmd
    }

    fn trace(&self) -> &Trace {
        self.inner.trace()
    }

    fn trace_mut(&mut self) -> &mut Trace {
        self.inner.trace_mut()
    }
}

#[test]
fn planning_cycles_do_not_allocate() {
    // The buffers see more than one kind of cycle there.
    let world = common::weaving_corridor();
    // Rayon's workers run the samples; planning calls are made from inside the pool so that
    // no call has to queue a job from outside it (which allocates the queue's blocks).
    let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
    let jackal = ComputeConfig {
        model: planner::compute::ComputeModel::JackalOnboardV2,
        ..ComputeConfig::FREE
    };
    let mut failures = Vec::new();
    for (fidelity, schedule) in [("vanilla", Schedule::vanilla()), ("ddp", Schedule::ddp_default())] {
        for metered in [false, true] {
            let planners: [Box<dyn Planner>; 4] = [
                Box::new(Dwa::new(DwaConfig::default())),
                Box::new(Mppi::new(MppiConfig::default(), 3)),
                Box::new(LogMppi::new(LogMppiConfig::default(), 3)),
                Box::new(NavSystem::new(SystemConfig::default(), 3)),
            ];
            for mut p in planners {
                let name = p.name();
                let compute = if metered {
                    jackal.resolve(name).unwrap()
                } else {
                    None
                };
                let mut counted = Counted {
                    inner: p.as_mut(),
                    armed: false,
                    calls: 0,
                    allocating: Vec::new(),
                    counted: 0,
                };
                // The first episode grows the buffers; the same episode again is counted.
                for armed in [false, true] {
                    counted.armed = armed;
                    pool.install(|| {
                        run_episode(
                            &world,
                            EpisodeConfig::default(),
                            &mut counted,
                            &schedule,
                            1.5,
                            7,
                            compute,
                            |_, _, _| {},
                        )
                    });
                }
                assert!(
                    counted.counted > 20,
                    "{name} {fidelity}: only {} counted cycles",
                    counted.counted
                );
                if !counted.allocating.is_empty() {
                    failures.push(format!(
                        "{name} {fidelity} (compute model {}): {} of {} cycles allocated, first (call, allocations) {:?}",
                        if metered { "on" } else { "off" },
                        counted.allocating.len(),
                        counted.counted,
                        &counted.allocating[..counted.allocating.len().min(5)]
                    ));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
