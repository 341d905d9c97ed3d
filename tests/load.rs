//! Load: 64 actor processes on this machine against one learner with the default heartbeat and
//! lease timing, half of them streaming steps over shared memory and half over gRPC. The run
//! must be lossless (every reported episode arrived whole, nothing refused or abandoned), no
//! lease may expire or be dropped, every rank must deliver, and the assignment cycle must turn
//! over at least once (all 64 actors finished their two episodes and took new work).
//!
//! Waits are bounded by a watchdog; nothing asserts a duration.

use std::process::{Child, Stdio};
use std::time::Duration;

use learner_service::read_status;

mod common;
use common::{adp, fresh_dir, spawn_actor, status};

/// Actor processes.
const ACTORS: u32 = 64;

/// Agent steps of the run: more than one cycle of 64 actors x 2 episodes needs.
const STEPS: u64 = 12_000;

#[test]
fn sixty_four_actors_over_both_planes_lose_nothing_and_keep_their_leases() {
    let _guard = testkit::watchdog(1800, "64-actor load run");
    let dir = fresh_dir("load-64");
    let run = dir.join("run");
    // Default heartbeat (1 s) and lease TTL (15 s). No TD3 updates (warm-up beyond the run):
    // the cores go to the actors and the data planes, which are what is loaded here.
    let cfg = dir.join("load.toml");
    std::fs::write(
        &cfg,
        "[td3]\nwarmup_steps = 1000000\n\n[service]\nshared_memory = true\nstatus_every_s = 0.5\n",
    )
    .unwrap();
    let mut learner = adp()
        .args(["learner", "--config"])
        .arg(&cfg)
        .args(["--steps", &STEPS.to_string(), "--listen", "127.0.0.1:0", "--out"])
        .arg(&run)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    for _ in 0..6000 {
        if run.join("learner.addr").is_file() {
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let addr = learner_service::read_addr(&run).unwrap();
    let token = run.join("token");
    let mut actors: Vec<(u32, Child)> = (0..ACTORS)
        .map(|r| {
            let plane = if r % 2 == 0 { "shm" } else { "grpc" };
            (r, spawn_actor(&addr, &token, r, plane))
        })
        .collect();

    // The learner ends at its budget; each actor leaves when told the run is over.
    let ended = learner.wait().unwrap();
    assert!(ended.success(), "learner: {ended:?}");
    for (rank, actor) in &mut actors {
        let exit = actor.wait().unwrap();
        assert!(exit.success(), "actor {rank}: {exit:?}");
    }

    let s = read_status(&run).unwrap();
    assert!(s.finished && s.inserts >= STEPS, "{s:?}");
    assert_eq!(s.shm_unavailable, None, "{s:?}");
    // No loss: every stored step is in the buffer, every reported episode arrived whole.
    assert!(s.replay_len as u64 >= s.inserts, "{s:?}");
    assert!(s.episodes >= u64::from(ACTORS) * 2, "{s:?}");
    assert_eq!(s.episodes_verified, s.episodes, "{s:?}");
    assert_eq!(s.episodes_mismatched, 0, "{s:?}");
    assert_eq!(s.episodes_abandoned, 0, "{s:?}");
    assert_eq!(s.refused.iter().map(|r| r.1).sum::<u64>(), 0, "{s:?}");
    // Heartbeats kept every lease alive under load, and no lease stalled.
    assert_eq!(s.leases_expired, 0, "{s:?}");
    assert_eq!(s.leases_dropped, 0, "{s:?}");
    // Every rank registered once and delivered its steps over its own plane only, and every
    // actor finished a cycle's two episodes.
    assert_eq!(s.ranks.len(), ACTORS as usize, "{s:?}");
    for r in &s.ranks {
        assert_eq!(r.registrations, 1, "rank {}: {s:?}", r.rank);
        let (mine, other) = if r.rank % 2 == 0 {
            (r.steps_shm, r.steps_grpc)
        } else {
            (r.steps_grpc, r.steps_shm)
        };
        assert!(mine > 0 && other == 0, "rank {}: {r:?}", r.rank);
    }
    assert!(s.cycle >= 1, "{s:?}");
    assert!(status(&run).is_some());
    std::fs::remove_dir_all(&dir).unwrap();
}
