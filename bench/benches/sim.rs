//! Simulator benchmarks: one lidar scan, and one control period (physics + scan + map +
//! global path) of an episode. Run with `cargo bench -p adp-bench --bench sim`.

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use sim::geometry::Pose;
use sim::lidar::{Lidar, LidarConfig, LidarRng};
use sim::{Episode, EpisodeConfig, Twist};

fn scan(c: &mut Criterion) {
    let world = sim::catalog::world(250).expect("embedded world");
    let lidar = Lidar::new(LidarConfig::default());
    let mut rng = LidarRng::new(1);
    let mut ranges = Vec::new();
    let scene = world.at(0.0);
    // Inside the obstacle field, where rays are shortest and the index busiest.
    let pose = Pose::new(-2.25, 6.5, 1.2);
    c.bench_function("lidar scan 720 beams (BARN world 250, in the field)", |b| {
        b.iter(|| {
            lidar.scan(&scene, black_box(&pose), &mut rng, &mut ranges);
            black_box(ranges[360])
        })
    });
}

fn control_period(c: &mut Criterion) {
    let world = sim::catalog::world(250).expect("embedded world");
    c.bench_function("episode step 0.05 s (physics + scan + costmap + path)", |b| {
        let mut ep = Episode::new(world, EpisodeConfig::default(), 1);
        b.iter(|| {
            if ep.step(Twist::new(0.0, 0.5)) != sim::Status::Running {
                ep = Episode::new(world, EpisodeConfig::default(), 1);
            }
        })
    });
}

criterion_group!(benches, scan, control_period);
criterion_main!(benches);
