//! Planner benchmarks: one DWA planning cycle under vanilla and DDP schedules, and one full
//! simulated second (20 cycles of scan + map + plan + physics). Run with
//! `cargo bench -p adp-planner`.

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use planner::{Dwa, DwaConfig, PlanInput, Planner, Schedule};
use sim::{Episode, EpisodeConfig};

/// An episode on a hard world, advanced into the obstacle field with DWA-DDP.
fn warm_episode(world: &sim::World) -> Episode<'_> {
    let mut ep = Episode::new(world, EpisodeConfig::default(), 3);
    let mut dwa = Dwa::new(DwaConfig::default());
    let sched = Schedule::ddp_default();
    for _ in 0..60 {
        let cmd = dwa.plan(&PlanInput {
            perception: ep.perception(),
            schedule: &sched,
            max_speed: 1.5,
        });
        ep.step(cmd);
    }
    ep
}

fn dwa_cycle(c: &mut Criterion) {
    let world = sim::barn::world(250).expect("embedded world");
    let ep = warm_episode(world);
    for (name, sched) in [("vanilla", Schedule::vanilla()), ("ddp", Schedule::ddp_default())] {
        let mut dwa = Dwa::new(DwaConfig::default());
        c.bench_function(&format!("dwa-{name} planning cycle (20x20 samples)"), |b| {
            b.iter(|| {
                black_box(dwa.plan(&PlanInput {
                    perception: ep.perception(),
                    schedule: &sched,
                    max_speed: 1.5,
                }))
            })
        });
    }
}

fn simulated_second(c: &mut Criterion) {
    let world = sim::barn::world(250).expect("embedded world");
    let sched = Schedule::ddp_default();
    c.bench_function("dwa-ddp one simulated second (20 cycles, everything)", |b| {
        let mut ep = warm_episode(world);
        let mut dwa = Dwa::new(DwaConfig::default());
        b.iter(|| {
            for _ in 0..20 {
                if ep.status() != sim::Status::Running {
                    ep = warm_episode(world);
                }
                let cmd = dwa.plan(&PlanInput {
                    perception: ep.perception(),
                    schedule: &sched,
                    max_speed: 1.5,
                });
                ep.step(cmd);
            }
            black_box(ep.sim_time())
        })
    });
}

criterion_group!(benches, dwa_cycle, simulated_second);
criterion_main!(benches);
