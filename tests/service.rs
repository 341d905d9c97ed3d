//! Multi-process tests of the training service: `adp train` over shared memory with 16 actors
//! and a resume; `adp learner` + `adp actor` over gRPC with an actor killed mid-episode, and
//! refused requests (no token, NaN, wrong length).
//!
//! Waits are bounded by a watchdog (a number of polls); nothing asserts a duration.

use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::time::Duration;

use learner_service::{read_status, Status};
use proto::grpc::LearnerAddress;
use proto::pb;

mod common;
use common::{adp, fresh_dir, refused, spawn_actor, status};

/// Polls `cond` every 100 ms; panics with `what` after `polls` polls (a watchdog against
/// deadlocks, not a timing assertion).
fn wait_for(what: &str, polls: u32, mut cond: impl FnMut() -> bool) {
    for _ in 0..polls {
        if cond() {
            return;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("watchdog: gave up waiting for {what}");
}

/// A config with a short warm-up and fast leases (and a laser clip other than the default, which
/// the export must record), for tests.
fn test_config(dir: &Path, shared_memory: bool) -> PathBuf {
    let text = format!(
        "[env]\nlaser_clip_m = 2.5\n\n[td3]\nwarmup_steps = 128\nrate_tolerance = 64.0\n\n[service]\nshared_memory = {shared_memory}\n\
         heartbeat_ms = 200\nlease_ttl_ms = 2000\nstatus_every_s = 0.2\ncheckpoint_replay = true\n"
    );
    let p = dir.join("test.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// Trains 600 steps with 16 actors in a fresh directory named `name`, over shared memory or
/// gRPC; returns the config, the run directory and the finished run's status.
fn train_sixteen(name: &str, shm: bool) -> (PathBuf, PathBuf, Status) {
    let dir = fresh_dir(name);
    let run = dir.join("run");
    let cfg = test_config(&dir, shm);
    let out = adp()
        .args(["train", "--config"])
        .arg(&cfg)
        .args(["--steps", "600", "--actors", "16", "--out"])
        .arg(&run)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    // The run directory holds the token and the operator credential: this user's only.
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(&run).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o700, "run directory mode {mode:o}");
    let s = read_status(&run).unwrap();
    (cfg, run, s)
}

#[test]
fn local_training_over_shared_memory_is_lossless_and_resumes() {
    let (cfg, run, s) = train_sixteen("train-shm", true);
    assert!(s.inserts >= 600, "{s:?}");
    assert_eq!(s.leases_expired, 0, "{s:?}");
    assert_eq!(s.episodes_abandoned, 0, "{s:?}");
    // Every stored step is in the buffer, and every reported episode arrived whole (its steps
    // matched the actor's count and checksum); these fail on a lost or duplicated record.
    assert!(s.replay_len as u64 >= s.inserts, "{s:?}");
    assert_eq!(s.episodes_verified, s.episodes, "{s:?}");
    assert!(s.episodes_verified > 0, "{s:?}");
    assert_eq!(s.episodes_mismatched, 0, "{s:?}");
    assert_eq!(s.refused.iter().map(|r| r.1).sum::<u64>(), 0, "{s:?}");
    // Every actor registered once, and every step it sent came over shared memory.
    assert_eq!(s.ranks.len(), 16, "{s:?}");
    for r in &s.ranks {
        assert_eq!(r.registrations, 1, "every actor registered once: {s:?}");
        assert_eq!(r.steps_grpc, 0, "rank {}: steps over gRPC: {s:?}", r.rank);
    }
    assert_eq!(
        s.ranks.iter().map(|r| r.steps_shm).sum::<u64>(),
        s.steps_received,
        "{s:?}"
    );
    assert!(run.join("export/policy.onnx").is_file());
    // The card documents the observation the actors made: the run's clip, not the default.
    let card: serde_json::Value =
        serde_json::from_slice(&std::fs::read(run.join("export/policy.json")).unwrap()).unwrap();
    assert_eq!(card["environment"]["laser_clip_m"], 2.5, "{card}");
    assert_eq!(card["environment"]["agent_period_cycles"], 5, "{card}");
    let laser = card["observation"]["segments"][0]["encoding"].as_str().unwrap();
    assert!(laser.contains("min(r, 2.5) / 2.5"), "{laser}");
    // And the planner and speed the run trained with, which the robot runtime checks.
    let run_config = std::fs::read_to_string(run.join("config.toml")).unwrap();
    let value = |key: &str| {
        let line = run_config
            .lines()
            .find(|l| l.starts_with(&format!("{key} = ")))
            .unwrap();
        line.split_once(" = ").unwrap().1.trim_matches('"').to_string()
    };
    assert_eq!(card["trained_for"]["planner"], value("planner"), "{card}");
    assert_eq!(
        card["trained_for"]["max_speed"].as_f64().unwrap(),
        value("max_speed").parse::<f64>().unwrap(),
        "{card}"
    );
    assert!(!learner::tensorboard::event_files(&run.join("tensorboard"))
        .unwrap()
        .is_empty());
    assert_resumes(&cfg, &run, &s);
}

#[test]
fn sixteen_actors_over_grpc_deliver_every_step_exactly_once() {
    let (cfg, run, s) = train_sixteen("train-grpc16", false);
    assert_eq!(s.rank_steps.len(), 16, "every actor delivered steps: {s:?}");
    // Every actor registered once and sent its steps over gRPC, none over shared memory.
    assert_eq!(s.ranks.len(), 16, "{s:?}");
    for r in &s.ranks {
        assert_eq!(r.registrations, 1, "every actor registered once: {s:?}");
        assert!(r.steps_grpc > 0 && r.steps_shm == 0, "rank {}: {s:?}", r.rank);
    }
    // Every stored step is in the buffer, and every reported episode arrived whole (its steps
    // matched the actor's count and checksum); these fail on a lost or duplicated record.
    assert!(s.replay_len as u64 >= s.inserts, "{s:?}");
    assert_eq!(s.episodes_verified, s.episodes, "{s:?}");
    assert!(s.episodes_verified >= 16, "{s:?}");
    assert_eq!(s.episodes_mismatched, 0, "{s:?}");
    assert_eq!(s.refused.iter().map(|r| r.1).sum::<u64>(), 0, "{s:?}");
    assert!(run.join("export/policy.onnx").is_file());
    assert!(!learner::tensorboard::event_files(&run.join("tensorboard"))
        .unwrap()
        .is_empty());

    assert_resumes(&cfg, &run, &s);
}

/// A fresh start in `run` is refused; `--resume` continues the same run past `first`.
fn assert_resumes(cfg: &Path, run: &Path, first: &Status) {
    let again = adp()
        .args(["train", "--config"])
        .arg(cfg)
        .args(["--steps", "900", "--actors", "2", "--out"])
        .arg(run)
        .output()
        .unwrap();
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--resume"));
    // Past what the first run stored (in-flight episodes overshoot its budget).
    let budget = (first.inserts + 300).to_string();
    let out = adp()
        .args(["train", "--config"])
        .arg(cfg)
        .args(["--steps", budget.as_str(), "--actors", "2", "--resume", "--out"])
        .arg(run)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let s = read_status(run).unwrap();
    assert_eq!(s.run_id, first.run_id);
    // It continued from the first run's final checkpoint (written once its budget was stored).
    let resumed = s
        .resumed_from
        .as_ref()
        .unwrap_or_else(|| panic!("the run did not resume: {s:?}"));
    assert!(
        resumed.inserts >= first.budget && resumed.inserts <= first.inserts,
        "{resumed:?} {first:?}"
    );
    assert!(
        s.inserts >= first.inserts + 300 && s.updates > first.updates,
        "{s:?}"
    );
    assert_eq!(s.episodes_mismatched, 0);
}

fn bad_step(obs: Vec<f32>) -> pb::StepRecord {
    pb::StepRecord {
        episode_id: 0,
        step_index: 0,
        policy_version: 0,
        obs: proto::floats::encode(&obs).into(),
        action: proto::floats::encode(&[0.0; 4]).into(),
        reward: 0.0,
        terminal: false,
        truncated: false,
        final_obs: Vec::new().into(),
    }
}

#[test]
fn grpc_learner_survives_a_killed_actor_and_refuses_bad_requests() {
    let dir = fresh_dir("learner-grpc");
    let run = dir.join("run");
    let cfg = test_config(&dir, false);
    let mut learner = adp()
        .args(["learner", "--config"])
        .arg(&cfg)
        .args(["--steps", "100000", "--listen", "127.0.0.1:0", "--out"])
        .arg(&run)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    wait_for("learner.addr", 600, || run.join("learner.addr").is_file());
    let addr = learner_service::read_addr(&run).unwrap();
    let token_file = run.join("token");
    let mut actors: Vec<Child> = (0..3)
        .map(|r| spawn_actor(&addr, &token_file, r, "grpc"))
        .collect();
    wait_for("steps from the actors", 1200, || {
        status(&run).is_some_and(|s| s.steps_received >= 200 && s.episodes_verified >= 1)
    });

    // kill -9 one actor mid-episode: its lease expires, the world is dealt again, the episode
    // is abandoned (not terminal), and the learner keeps training. Mid-episode = its step
    // count just moved (an actor that has finished its two episodes idles without a lease).
    let rank2 =
        |s: &learner_service::Status| s.rank_steps.iter().find(|(r, _)| *r == 2).map_or(0, |(_, n)| *n);
    let mut last = status(&run).map_or(0, |s| rank2(&s));
    wait_for("actor 2 streaming steps", 1200, || {
        let now = status(&run).map_or(last, |s| rank2(&s));
        let moved = now > last;
        last = now;
        moved
    });
    actors[2].kill().unwrap();
    actors[2].wait().unwrap();
    wait_for("the killed actor's lease to expire", 600, || {
        status(&run).is_some_and(|s| s.leases_expired >= 1)
    });
    let before = status(&run).unwrap();
    wait_for("training to go on", 600, || {
        status(&run).is_some_and(|s| s.steps_received > before.steps_received + 50)
    });

    // Bad requests are refused and counted.
    let rt = tokio::runtime::Runtime::new().unwrap();
    let token = proto::auth::read_token_file(&token_file).unwrap();
    rt.block_on(async {
        let no_token = LearnerAddress {
            addr: addr.clone(),
            token: None,
            tls: None,
        };
        let (mut control, _) = no_token.connect().await.unwrap();
        let e = control
            .register(pb::RegisterRequest::default())
            .await
            .unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unauthenticated);

        let with_token = LearnerAddress {
            addr: addr.clone(),
            token: Some(token),
            tls: None,
        };
        let (mut control, mut data) = with_token.connect().await.unwrap();
        let reg = control
            .register(pb::RegisterRequest {
                rank: 99,
                ..Default::default()
            })
            .await
            .unwrap()
            .into_inner();
        let run_ref = reg.run.unwrap();
        let lease = loop {
            let r = control
                .next_assignment(pb::AssignmentRequest {
                    run: Some(run_ref.clone()),
                    actor_id: reg.actor_id,
                    actor_secret: reg.actor_secret.clone(),
                })
                .await
                .unwrap()
                .into_inner();
            match r.decision {
                Some(pb::assignment_reply::Decision::Assign(a)) => break a,
                _ => tokio::time::sleep(Duration::from_millis(100)).await,
            }
        };
        let mut nan = vec![0.5f32; 730];
        nan[3] = f32::NAN;
        let batch = pb::StepBatch {
            run: Some(run_ref.clone()),
            actor_id: reg.actor_id,
            lease_id: lease.lease_id,
            actor_secret: reg.actor_secret.clone(),
            steps: vec![
                pb::StepRecord {
                    episode_id: lease.first_episode_id,
                    ..bad_step(nan)
                },
                pb::StepRecord {
                    episode_id: lease.first_episode_id,
                    ..bad_step(vec![0.5; 729])
                },
            ],
        };
        let ack = data
            .push_steps(tokio_stream::iter(vec![batch]))
            .await
            .unwrap()
            .into_inner();
        assert_eq!((ack.accepted, ack.refused), (0, 2), "{ack:?}");
        assert!(ack.reason.contains("not finite"), "{}", ack.reason);
    });
    wait_for("refusals in status.json", 100, || {
        status(&run).is_some_and(|s| {
            refused(&s, "unauthenticated") >= 1
                && refused(&s, "not_finite") == 1
                && refused(&s, "bad_shape") == 1
        })
    });

    // Stop the learner with SIGTERM: it checkpoints and exits cleanly; actors exit 0 on shutdown.
    // SAFETY: kill(2) on a child's pid has no memory-safety preconditions.
    assert_eq!(unsafe { libc::kill(learner.id() as i32, libc::SIGTERM) }, 0);
    let code = learner.wait().unwrap();
    assert!(code.success(), "{code:?}");
    let s = read_status(&run).unwrap();
    assert_eq!(s.episodes_mismatched, 0, "{s:?}");
    // An episode the killed actor left open is abandoned (its tail never sampled, never marked
    // terminal); it may also have died between episodes.
    assert!(s.episodes_abandoned <= s.leases_expired, "{s:?}");
    assert!(learner::retention::latest(&run.join("checkpoints"))
        .unwrap()
        .is_some());
    for mut a in actors.drain(..2) {
        let _ = a.kill();
        let _ = a.wait();
    }
}
