//! Hostile peers (issue 30) against a real `adp learner`: raw TCP connections that never send
//! the HTTP/2 preface are closed while an honest client is served; unread `WatchPolicy`
//! streams share one copy of the policy; thousands of distinct ranks do not grow `status.json`
//! without bound; a report with an enum value outside the contract is refused, naming the
//! field, and the run goes on; at a 64-file limit (`prlimit`: the test skips without it, unless
//! `ADP_REQUIRE_PRLIMIT=1`, set by `.ci/run`, where that is a failure) an honest actor is served
//! and the SIGTERM checkpoint completes. Every wait is a bounded poll (a watchdog), never a
//! timing assertion.

use std::io::Read;
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::time::Duration;

use proto::grpc::LearnerAddress;
use proto::pb;

mod common;
use common::{adp, fresh_dir, refused, status};

/// Polls of a watchdog that should never fire (100 ms apart: about five minutes).
const PATIENCE: u32 = 3000;

/// Kills the learner when a test fails.
struct Learner(Child);

impl Drop for Learner {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `adp learner` in `dir/run` with the default network sizes and `service` appended to
/// the `[service]` table; returns it with the run directory, address and token.
fn learner(dir: &Path, service: &str) -> (Learner, PathBuf, String, String) {
    let cfg = dir.join("test.toml");
    std::fs::write(
        &cfg,
        format!(
            "[service]\nshared_memory = false\nddp_init = false\nheartbeat_ms = 200\nlease_ttl_ms = 1000\n\
             status_every_s = 0.2\n{service}\n"
        ),
    )
    .unwrap();
    let run = dir.join("run");
    let child = adp()
        .args(["learner", "--config"])
        .arg(&cfg)
        .args(["--steps", "100000", "--listen", "127.0.0.1:0", "--out"])
        .arg(&run)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("learner.stderr")).unwrap())
        .spawn()
        .unwrap();
    let learner = Learner(child);
    poll("learner.addr", || run.join("learner.addr").is_file());
    poll("the first status", || status(&run).is_some());
    let addr = learner_service::read_addr(&run).unwrap();
    let token = proto::auth::read_token_file(&run.join("token")).unwrap();
    (learner, run, addr, token)
}

/// Waits (a watchdog of [`PATIENCE`] polls) until `cond` holds.
fn poll(what: &str, mut cond: impl FnMut() -> bool) {
    for _ in 0..PATIENCE {
        if cond() {
            return;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("watchdog: gave up waiting for {what}");
}

/// The resident set of process `pid` in KiB.
fn rss_kib(pid: u32) -> u64 {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    text.lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap()
}

/// Registers an actor of `rank`; returns its clients, run and the reply.
async fn register(
    addr: &str,
    token: &str,
    rank: u32,
) -> (
    proto::grpc::ControlClient,
    proto::grpc::DataClient,
    pb::RegisterReply,
) {
    let a = LearnerAddress {
        addr: addr.to_owned(),
        token: Some(token.to_owned()),
        tls: None,
    };
    let (mut control, data) = a.connect().await.unwrap();
    let reply = control
        .register(pb::RegisterRequest {
            rank,
            host: "test".into(),
            pid: 1,
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    (control, data, reply)
}

#[test]
fn silent_connections_are_closed_while_an_honest_actor_is_served() {
    let dir = fresh_dir("hostile-silent");
    let (_learner, _run, addr, token) = learner(&dir, "handshake_timeout_ms = 1000");
    let mut silent: Vec<TcpStream> = (0..500).map(|_| TcpStream::connect(&addr).unwrap()).collect();
    let rt = tokio::runtime::Runtime::new().unwrap();
    // An honest actor registers and heartbeats meanwhile.
    rt.block_on(async {
        let (mut control, _data, reply) = register(&addr, &token, 0).await;
        let hb = control
            .heartbeat(pb::HeartbeatRequest {
                run: reply.run.clone(),
                actor_id: reply.actor_id,
                lease_id: 0,
                actor_secret: reply.actor_secret.clone(),
            })
            .await
            .unwrap()
            .into_inner();
        assert!(!hb.shutdown);
    });
    // Every silent connection is closed by the learner (EOF or reset on read).
    for s in &silent {
        s.set_read_timeout(Some(Duration::from_millis(100))).unwrap();
    }
    let mut open = silent.len();
    for _ in 0..PATIENCE {
        silent.retain_mut(|s| {
            let mut buf = [0u8; 256];
            loop {
                match s.read(&mut buf) {
                    Ok(0) => return false,
                    // The server's SETTINGS frame: read on.
                    Ok(_) => continue,
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) =>
                    {
                        return true
                    }
                    Err(_) => return false,
                }
            }
        });
        open = silent.len();
        if open == 0 {
            break;
        }
    }
    assert_eq!(open, 0, "watchdog: silent connections still open");
}

/// 500 unread WatchPolicy streams (250 actors x the per-actor cap of 2) cost the learner
/// little memory, and closing them gives their places and memory back: three rounds of 500
/// (1,500 streams in all, over the global cap of 1,024 if places were never returned) stay
/// under the same bound, and so does the learner after the last round closed.
#[test]
fn unread_policy_streams_share_one_policy_copy() {
    let dir = fresh_dir("hostile-watch");
    let (learner, _run, addr, token) = learner(&dir, "");
    let pid = learner.0.id();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let before = rss_kib(pid);
    let bound = before + 50 * 1024;
    for round in 0..3 {
        let streams = rt.block_on(async {
            let mut streams = Vec::new();
            for rank in 0..250 {
                let (_control, mut data, reply) = register(&addr, &token, rank).await;
                let request = || pb::PolicyRequest {
                    run: reply.run.clone(),
                    actor_id: reply.actor_id,
                    have_version: 0,
                    actor_secret: reply.actor_secret.clone(),
                };
                for _ in 0..2 {
                    streams.push(data.watch_policy(request()).await.unwrap());
                }
                // A third stream of the same actor is over the per-actor cap.
                let third = data.watch_policy(request()).await.unwrap_err();
                assert_eq!(third.code(), tonic::Code::ResourceExhausted, "{third}");
            }
            streams
        });
        // Let the learner push what it can into the 500 unread streams.
        std::thread::sleep(Duration::from_secs(2));
        let with_streams = rss_kib(pid);
        eprintln!("round {round}: learner RSS {before} KiB before, {with_streams} KiB with 500 unread WatchPolicy streams");
        assert!(
            with_streams < bound,
            "round {round}: RSS grew from {before} to {with_streams} KiB"
        );
        drop(streams);
        std::thread::sleep(Duration::from_secs(1));
    }
    let after = rss_kib(pid);
    eprintln!("learner RSS after the streams closed: {after} KiB");
    assert!(
        after < bound,
        "RSS {after} KiB after closing, {before} KiB before"
    );
}

#[test]
fn ten_thousand_distinct_ranks_leave_a_small_status() {
    let dir = fresh_dir("hostile-ranks");
    let (_learner, run, addr, token) = learner(&dir, "rank_forget_ms = 2000\ndead_ranks_kept = 64");
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let a = LearnerAddress {
            addr: addr.clone(),
            token: Some(token.clone()),
            tls: None,
        };
        let (mut control, _data) = a.connect().await.unwrap();
        for rank in 0..10_000 {
            control
                .register(pb::RegisterRequest {
                    rank,
                    host: "test".into(),
                    pid: 1,
                    ..Default::default()
                })
                .await
                .unwrap();
        }
    });
    poll("a small status.json", || {
        let size = std::fs::metadata(run.join("status.json")).map_or(u64::MAX, |m| m.len());
        status(&run).is_some_and(|s| s.pruned_ranks.ranks >= 9_000 && s.ranks.len() <= 64)
            && size < 100 * 1024
    });
}

/// Oversized requests (a 64 KiB+ registration, a 1 MiB+ step batch) are refused with
/// RESOURCE_EXHAUSTED, and the learner serves the next request. Also prints (never asserts)
/// how long `Register` and `Heartbeat` take on this idle loopback learner.
#[test]
fn oversized_requests_are_resource_exhausted() {
    let dir = fresh_dir("hostile-sizes");
    let (_learner, _run, addr, token) = learner(&dir, "");
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let (mut control, mut data, reply) = register(&addr, &token, 0).await;
        let big = control
            .register(pb::RegisterRequest {
                rank: 1,
                host: "h".repeat(proto::grpc::MAX_CONTROL_REQUEST_BYTES + 1),
                pid: 1,
                ..Default::default()
            })
            .await
            .unwrap_err();
        assert_eq!(big.code(), tonic::Code::ResourceExhausted, "{big}");
        let batch = pb::StepBatch {
            run: reply.run.clone(),
            actor_id: reply.actor_id,
            lease_id: 1,
            actor_secret: reply.actor_secret.clone(),
            steps: vec![pb::StepRecord {
                obs: vec![0u8; proto::grpc::MAX_REQUEST_BYTES + 4].into(),
                ..Default::default()
            }],
        };
        let big = data.push_steps(tokio_stream::iter([batch])).await.unwrap_err();
        assert_eq!(big.code(), tonic::Code::ResourceExhausted, "{big}");

        // Timings (printed, not asserted): each call over the same TCP connection.
        let times = |label: &str, mut v: Vec<Duration>| {
            v.sort();
            eprintln!(
                "{label}: median {:?}, p90 {:?}, max {:?} over {} calls",
                v[v.len() / 2],
                v[v.len() * 9 / 10],
                v[v.len() - 1],
                v.len()
            );
        };
        let mut regs = Vec::new();
        for rank in 0..200 {
            let t = std::time::Instant::now();
            control
                .register(pb::RegisterRequest {
                    rank: 100 + rank,
                    host: "test".into(),
                    pid: 1,
                    ..Default::default()
                })
                .await
                .unwrap();
            regs.push(t.elapsed());
        }
        times("Register", regs);
        let mut beats = Vec::new();
        for _ in 0..200 {
            let t = std::time::Instant::now();
            control
                .heartbeat(pb::HeartbeatRequest {
                    run: reply.run.clone(),
                    actor_id: reply.actor_id,
                    lease_id: 0,
                    actor_secret: reply.actor_secret.clone(),
                })
                .await
                .unwrap();
            beats.push(t.elapsed());
        }
        times("Heartbeat", beats);
    });
}

/// The run spec is typed: an actor reads the planner, action space and environment settings
/// from it (and they size the observation the learner trains on). A report whose `outcome` is
/// no `Outcome` value is refused with INVALID_ARGUMENT naming the field; it is counted, the
/// actor keeps its lease and the learner keeps serving.
#[test]
fn the_run_spec_is_typed_and_an_unknown_outcome_is_refused_while_the_run_goes_on() {
    let dir = fresh_dir("hostile-enums");
    let (_learner, run, addr, token) = learner(&dir, "");
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let (mut control, _data, reply) = register(&addr, &token, 0).await;
        let spec = reply.spec.clone().unwrap();
        let space = actor::spec::action_space_from_wire(spec.action_space.as_ref().unwrap()).unwrap();
        let env = actor::spec::env_from_wire(spec.env.as_ref().unwrap()).unwrap();
        actor::spec::planner_from_wire("spec.planner", spec.planner).unwrap();
        assert_eq!(
            spec.obs_dim as usize,
            actor::obs_dim(env.observation, space, env.observe_tracks)
        );
        assert_eq!(spec.act_dim as usize, space.dim());
        let assignment = control
            .next_assignment(pb::AssignmentRequest {
                run: reply.run.clone(),
                actor_id: reply.actor_id,
                actor_secret: reply.actor_secret.clone(),
            })
            .await
            .unwrap()
            .into_inner();
        let Some(pb::assignment_reply::Decision::Assign(a)) = assignment.decision else {
            panic!("no assignment: {assignment:?}");
        };
        let bad = control
            .report_episode(pb::EpisodeReport {
                run: reply.run.clone(),
                actor_id: reply.actor_id,
                lease_id: a.lease_id,
                actor_secret: reply.actor_secret.clone(),
                episode_id: a.first_episode_id,
                world: a.world,
                outcome: 99,
                ..Default::default()
            })
            .await
            .unwrap_err();
        assert_eq!(bad.code(), tonic::Code::InvalidArgument, "{bad}");
        assert!(bad.message().contains("`outcome` = 99"), "{bad}");
        let beat = control
            .heartbeat(pb::HeartbeatRequest {
                run: reply.run.clone(),
                actor_id: reply.actor_id,
                lease_id: a.lease_id,
                actor_secret: reply.actor_secret.clone(),
            })
            .await
            .unwrap()
            .into_inner();
        assert!(beat.lease_valid && !beat.shutdown, "{beat:?}");
    });
    poll("the refusal in status.json", || {
        status(&run).is_some_and(|s| refused(&s, "out_of_range") == 1 && !s.finished)
    });
}

/// Whether `program` (the `prlimit` of util-linux, or a stand-in in a test) runs here, as
/// `program --version`; when it does not, the test that needs it is skipped with the reason,
/// unless `required` (`ADP_REQUIRE_PRLIMIT=1`, set by `.ci/run`), where that is a failure.
fn prlimit_or_skip(program: &str, required: bool) -> bool {
    let why = match std::process::Command::new(program).arg("--version").output() {
        Ok(o) if o.status.success() => return true,
        Ok(o) => format!("`{program} --version` failed ({})", o.status),
        Err(e) => format!("`{program}` cannot run: {e}"),
    };
    assert!(
        !required,
        "ADP_REQUIRE_PRLIMIT=1 but prlimit is not usable (Debian's util-linux provides it): {why}"
    );
    eprintln!("SKIPPED: no prlimit: {why}");
    false
}

/// Without `prlimit` the 64-file test skips, saying why; with `ADP_REQUIRE_PRLIMIT=1` it fails
/// instead, naming the switch and the reason.
#[test]
fn a_missing_prlimit_skips_unless_required() {
    let missing = "adp-test-no-such-prlimit";
    assert!(!prlimit_or_skip(missing, false));
    let failure = std::panic::catch_unwind(|| prlimit_or_skip(missing, true)).unwrap_err();
    let msg = failure
        .downcast_ref::<String>()
        .expect("a formatted panic message");
    assert!(
        msg.starts_with("ADP_REQUIRE_PRLIMIT=1 but prlimit is not usable")
            && msg.contains("`adp-test-no-such-prlimit` cannot run"),
        "{msg}"
    );
}

/// With the open-file limit at 64 (soft and hard, so the learner cannot raise it) and silent
/// connections queued far beyond it, the learner still serves an honest actor, and on SIGTERM
/// its checkpoint completes: the run resumes from it. Skipped without `prlimit`, unless
/// `ADP_REQUIRE_PRLIMIT=1`.
#[test]
fn at_a_64_file_limit_an_honest_actor_is_served_and_the_sigterm_checkpoint_completes() {
    let required = std::env::var("ADP_REQUIRE_PRLIMIT").as_deref() == Ok("1");
    if !prlimit_or_skip("prlimit", required) {
        return;
    }
    let dir = fresh_dir("hostile-nofile");
    let cfg = dir.join("test.toml");
    std::fs::write(
        &cfg,
        "[service]\nshared_memory = false\nddp_init = false\nheartbeat_ms = 200\nlease_ttl_ms = 1000\n\
         status_every_s = 0.2\nhandshake_timeout_ms = 1000\n",
    )
    .unwrap();
    let run = dir.join("run");
    let start = |resume: bool| {
        let mut cmd = std::process::Command::new("prlimit");
        if !resume {
            cmd.arg("--nofile=64:64");
        }
        cmd.arg("--")
            .arg(adp().get_program())
            .args(["learner", "--config"])
            .arg(&cfg)
            .args(["--steps", "100000", "--listen", "127.0.0.1:0", "--out"])
            .arg(&run);
        if resume {
            cmd.arg("--resume");
        }
        let log = if resume {
            "resumed.stderr"
        } else {
            "learner.stderr"
        };
        Learner(
            cmd.stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(dir.join(log)).unwrap())
                .spawn()
                .unwrap(),
        )
    };
    let mut learner = start(false);
    poll("learner.addr", || run.join("learner.addr").is_file());
    poll("the first status", || status(&run).is_some());
    let addr = learner_service::read_addr(&run).unwrap();
    let token = proto::auth::read_token_file(&run.join("token")).unwrap();
    // Far more silent connections than the learner has descriptors: the kernel queues them;
    // the learner takes what its cap allows and closes each after the handshake timeout.
    let silent: Vec<TcpStream> = (0..200).map(|_| TcpStream::connect(&addr).unwrap()).collect();
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let (mut control, _data, reply) = register(&addr, &token, 0).await;
        for _ in 0..5 {
            let hb = control
                .heartbeat(pb::HeartbeatRequest {
                    run: reply.run.clone(),
                    actor_id: reply.actor_id,
                    lease_id: 0,
                    actor_secret: reply.actor_secret.clone(),
                })
                .await
                .unwrap()
                .into_inner();
            assert!(!hb.shutdown);
        }
    });
    // More silent connections while the learner stops: its checkpoint must still be written.
    let more: Vec<TcpStream> = (0..100).map(|_| TcpStream::connect(&addr).unwrap()).collect();
    let stopped = unsafe { libc::kill(learner.0.id() as i32, libc::SIGTERM) };
    assert_eq!(stopped, 0);
    let mut code = None;
    poll("the learner to exit after SIGTERM", || {
        code = learner.0.try_wait().unwrap();
        code.is_some()
    });
    let log = std::fs::read_to_string(dir.join("learner.stderr")).unwrap();
    assert!(code.unwrap().success(), "{code:?}\n{log}");
    drop((silent, more));
    let first = status(&run).unwrap();
    assert!(first.finished, "{first:?}");
    let _resumed = start(true);
    poll("the resumed learner's status", || {
        status(&run).is_some_and(|s| s.incarnation != first.incarnation)
    });
    let s = status(&run).unwrap();
    assert!(
        s.resumed_from.is_some(),
        "no checkpoint to resume from: {s:?}\n{log}"
    );
}
