//! Behaviour pins: each planner x fidelity drives a short corridor episode to a trajectory
//! checksum that must not change. A speed-up that changes floating-point results, or any
//! behaviour change, fails here; a deliberate change updates the pins and says why.

mod common;

use planner::run::run_episode;
use planner::{
    Dwa, DwaConfig, LogMppi, LogMppiConfig, Mppi, MppiConfig, NavSystem, Planner, Schedule, SystemConfig,
};
use sim::{EpisodeConfig, World};

/// FNV-1a over the exact bits of every pose the robot passes at each planning cycle, and of
/// the result.
fn checksum(planner: &mut dyn Planner, schedule: &Schedule, world: &World) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bits: u64| {
        for b in bits.to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    let (result, cycles) = run_episode(
        world,
        EpisodeConfig::default(),
        planner,
        schedule,
        1.5,
        7,
        // The free compute model: these pins are the behaviour from before the model.
        None,
        |ep, _, cmd| {
            let s = ep.state();
            for x in [s.pose.x, s.pose.y, s.pose.yaw, cmd.v, cmd.w] {
                eat(x.to_bits());
            }
        },
    );
    eat(cycles.cycles);
    for x in [result.time_s, result.distance_m] {
        eat(x.to_bits());
    }
    h
}

#[test]
fn every_planner_reproduces_its_trajectory() {
    let world = common::weaving_corridor();
    let mut got = Vec::new();
    for (fidelity, schedule) in [("vanilla", Schedule::vanilla()), ("ddp", Schedule::ddp_default())] {
        let planners: [(&str, Box<dyn Planner>); 4] = [
            ("dwa", Box::new(Dwa::new(DwaConfig::default()))),
            ("mppi", Box::new(Mppi::new(MppiConfig::default(), 3))),
            ("log-mppi", Box::new(LogMppi::new(LogMppiConfig::default(), 3))),
            ("system", Box::new(NavSystem::new(SystemConfig::default(), 3))),
        ];
        for (name, mut p) in planners {
            got.push(format!(
                "{name} {fidelity} {:#018x}",
                checksum(p.as_mut(), &schedule, &world)
            ));
        }
    }
    // Updated when `Vec2::norm` changed from `hypot` to `sqrt(x^2 + y^2)` (last-bit changes
    // in MPPI, Log-MPPI and the system; on 75 BARN worlds x 8 rows every run kept its status,
    // time and score).
    let want = [
        "dwa vanilla 0x333f65407c501733",
        "mppi vanilla 0x08e43228411f9045",
        "log-mppi vanilla 0xc9d62cdfbd611cb7",
        "system vanilla 0xcfee9b4e4237c4e1",
        "dwa ddp 0x94949ef171af0d89",
        "mppi ddp 0x42d29f9ccf48d000",
        "log-mppi ddp 0x78a8b0232b9b68fc",
        "system ddp 0x9e94cb00dad12c96",
    ];
    assert_eq!(got, want);
}
