//! Hostile peers (issue 30) against a real `adp learner`: raw TCP connections that never send
//! the HTTP/2 preface are closed while an honest client is served; unread `WatchPolicy`
//! streams share one copy of the policy; thousands of distinct ranks do not grow `status.json`
//! without bound. Every wait is a bounded poll (a watchdog), never a timing assertion.

use std::io::Read;
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::time::Duration;

use proto::grpc::LearnerAddress;
use proto::pb;

mod common;
use common::{adp, fresh_dir, status};

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
    let addr = learner::service::read_addr(&run).unwrap();
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

#[test]
fn unread_policy_streams_share_one_policy_copy() {
    let dir = fresh_dir("hostile-watch");
    let (learner, _run, addr, token) = learner(&dir, "");
    let pid = learner.0.id();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let before = rss_kib(pid);
    let streams = rt.block_on(async {
        let mut streams = Vec::new();
        for rank in 0..250 {
            let (_control, mut data, reply) = register(&addr, &token, rank).await;
            for _ in 0..2 {
                let r = data
                    .watch_policy(pb::PolicyRequest {
                        run: reply.run.clone(),
                        actor_id: reply.actor_id,
                        have_version: 0,
                        actor_secret: reply.actor_secret.clone(),
                    })
                    .await
                    .unwrap();
                streams.push(r);
            }
            // A third stream of the same actor is over the per-actor cap.
            let third = data
                .watch_policy(pb::PolicyRequest {
                    run: reply.run.clone(),
                    actor_id: reply.actor_id,
                    have_version: 0,
                    actor_secret: reply.actor_secret.clone(),
                })
                .await
                .unwrap_err();
            assert_eq!(third.code(), tonic::Code::ResourceExhausted, "{third}");
        }
        streams
    });
    // Let the learner push what it can into the 500 unread streams.
    std::thread::sleep(Duration::from_secs(2));
    let with_streams = rss_kib(pid);
    eprintln!("learner RSS: {before} KiB before, {with_streams} KiB with 500 unread WatchPolicy streams");
    assert!(
        with_streams < before + 50 * 1024,
        "RSS grew from {before} to {with_streams} KiB"
    );
    drop(streams);
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
