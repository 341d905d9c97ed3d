//! Planner benchmarks: one planning cycle of every planner under vanilla and DDP schedules
//! (DESIGN §8: DWA-DDP <= 0.5 ms, MPPI-550 <= 2 ms), and one full
//! simulated second (20 cycles of scan + map + plan + physics). Run with
//! `cargo bench -p adp-bench --bench planner`.

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use planner::{
    Dwa, DwaConfig, LogMppi, LogMppiConfig, Mppi, MppiConfig, NavSystem, PlanInput, Planner, Schedule,
    SystemConfig,
};
use sim::{Episode, EpisodeConfig};

/// The planning input of `ep`'s current cycle at 1.5 m/s with `sched` and the papers' model.
fn input<'a>(ep: &'a Episode<'_>, sched: &'a Schedule) -> PlanInput<'a> {
    PlanInput {
        perception: ep.perception(),
        schedule: sched,
        max_speed: 1.5,
        prediction: planner::Prediction::PAPERS,
        budget: planner::Budget::UNLIMITED,
        moving: &[],
    }
}

/// An episode on a hard world, advanced into the obstacle field with DWA-DDP.
fn warm_episode(world: &sim::World) -> Episode<'_> {
    let mut ep = Episode::new(world, EpisodeConfig::default(), 3);
    let mut dwa = Dwa::new(DwaConfig::default());
    let sched = Schedule::ddp_default();
    for _ in 0..60 {
        let cmd = dwa.plan(&input(&ep, &sched));
        ep.step(cmd);
    }
    ep
}

fn planning_cycles(c: &mut Criterion) {
    let world = sim::catalog::world(250).expect("embedded world");
    let ep = warm_episode(world);
    type Make = fn() -> Box<dyn Planner>;
    let planners: [(&str, Make); 4] = [
        ("dwa", || Box::new(Dwa::new(DwaConfig::default()))),
        ("mppi", || Box::new(Mppi::new(MppiConfig::default(), 1))),
        ("log-mppi", || Box::new(LogMppi::new(LogMppiConfig::default(), 1))),
        ("system", || Box::new(NavSystem::new(SystemConfig::default(), 1))),
    ];
    for (planner, make) in planners {
        for (fidelity, sched) in [("vanilla", Schedule::vanilla()), ("ddp", Schedule::ddp_default())] {
            let mut p = make();
            c.bench_function(&format!("{planner}-{fidelity} planning cycle"), |b| {
                b.iter(|| black_box(p.plan(&input(&ep, &sched))))
            });
        }
    }
}

fn simulated_second(c: &mut Criterion) {
    let world = sim::catalog::world(250).expect("embedded world");
    let sched = Schedule::ddp_default();
    c.bench_function("dwa-ddp one simulated second (20 cycles, everything)", |b| {
        let mut ep = warm_episode(world);
        let mut dwa = Dwa::new(DwaConfig::default());
        b.iter(|| {
            for _ in 0..20 {
                if ep.status() != sim::Status::Running {
                    ep = warm_episode(world);
                }
                let cmd = dwa.plan(&input(&ep, &sched));
                ep.step(cmd);
            }
            black_box(ep.sim_time())
        })
    });
}

criterion_group!(benches, planning_cycles, simulated_second);
criterion_main!(benches);
