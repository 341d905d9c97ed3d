//! `adp bench load` (issue 71, item 4): many light actors against one `adp learner` for a
//! few minutes, over gRPC or shared memory: steps stored per second, the latency of a step
//! stream's acknowledgement (gRPC) or delivery (shared memory), the learner's resident memory,
//! registrations per second, and whether anything was lost.
//!
//! A *light actor* is one thread of this process doing what an `adp actor` process does, with
//! synthetic steps instead of a simulator: its own HTTP/2 connection (over TCP to
//! `127.0.0.1` for the gRPC plane, as actors on other hosts connect, all from one address;
//! over the learner's Unix socket for shared memory, as `adp train` connects the actors on its
//! host), its own registration (`Register` with its rank), a heartbeat every `heartbeat_ms`
//! (a task on a tokio runtime of two workers that every light actor shares), its own policy
//! source (a `WatchPolicy` stream, or an iceoryx2 subscriber on its own node), and its own
//! step sink, the real actor's ([`GrpcStepSink`]: one `PushSteps` stream per episode, closed
//! and acknowledged at the episode's end; or [`ShmStepSink`] on its own iceoryx2 node). It asks
//! for assignments, waits for the assignment's policy version, sends each episode's steps as
//! fast as the sink takes them (no pacing: the learner sets the pace), and reports each
//! episode with its step count and checksum.
//!
//! The learner runs as a child process (`adp learner`) with no TD3 updates (so its rate
//! limiter never holds actors up: what is measured is the service), configured as a run of
//! that many actors must be (see [`learner_config`]). Figures come from its `status.json` and
//! `/proc`; the rates count over a window that opens 10 s after the last registration.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Barrier};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant, SystemTime};

use actor::run::{heartbeats, AbortOnDrop, Flags};
use anyhow::{anyhow, bail, Context};
use learner_service::{read_addr, read_status, ServiceConfig, Status};
use proto::checksum::step_checksum;
use proto::grpc::{ControlClient, GrpcPolicySource, GrpcStepSink, LearnerAddress};
use proto::pb;
use proto::plane::{LeaseHeader, PlaneError, PolicySource, SinkTally, StepSink};
use proto::shm::{ShmConfig, ShmPolicySource, ShmStepSink};
use proto::StepView;
use tokio::runtime::Handle;

use crate::compute::percentile;
use crate::{figure, tempdir, Figure};

/// The data plane the light actors stream their steps over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum LoadPlane {
    /// gRPC over TCP to 127.0.0.1 (policies over `WatchPolicy`).
    Grpc,
    /// iceoryx2 shared memory (policies too); the control plane over the learner's Unix socket.
    Shm,
}

/// What the `load` part runs.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadOptions {
    /// Light actors.
    pub actors: u32,
    /// Their data plane.
    pub plane: LoadPlane,
    /// Length of the measured window (s), after the registrations and a 10 s warm-up.
    pub seconds: u64,
    /// Steps per synthetic episode (at most the run's `max_agent_steps`, 200).
    pub episode_steps: u32,
    /// Keep the learner's default per-address and per-learner caps instead of raising them to
    /// the actor count (shows what a run that did not raise them gets).
    pub default_limits: bool,
}

/// Time from the last registration to the opening of the measured window.
const WARMUP: Duration = Duration::from_secs(10);
/// How long the light actors get to register before the window opens without the missing ones.
const REGISTRATION_PATIENCE: Duration = Duration::from_secs(120);

/// The learner's configuration for `o`: no TD3 updates, and (unless `o.default_limits`) every
/// cap that a run of `o.actors` actors reaches raised to the actor count. Those are, over TCP
/// from one address: `max_connections_per_ip`, `registrations_per_ip`, `policy_streams_per_ip`
/// (one connection, registration and policy stream per actor); on any listener
/// `max_connections` and `max_policy_streams`; on shared memory `shm_max_actors`.
pub fn learner_config(o: &LoadOptions) -> String {
    let d = ServiceConfig::default();
    let n = o.actors;
    let mut text = format!(
        "[td3]\n# No updates: the rate limiter never holds the actors up.\nwarmup_steps = 1000000000\n\n\
         [service]\nshared_memory = {}\nddp_init = false\nstatus_every_s = 1.0\n",
        o.plane == LoadPlane::Shm
    );
    if !o.default_limits {
        for (key, default) in [
            ("max_connections", d.max_connections),
            ("max_connections_per_ip", d.max_connections_per_ip),
            ("registrations_per_ip", d.registrations_per_ip),
            ("policy_streams_per_ip", d.policy_streams_per_ip),
            ("max_policy_streams", d.max_policy_streams),
            ("shm_max_actors", d.shm_max_actors),
        ] {
            text.push_str(&format!("{key} = {}\n", n.max(default)));
        }
    }
    text
}

/// What every light actor shares.
struct Fleet {
    /// TCP address or `unix:` socket, and the token.
    address: LearnerAddress,
    plane: LoadPlane,
    episode_steps: u32,
    /// The runtime that drives every actor's calls and heartbeats.
    handle: Handle,
    /// Every actor and the measuring thread start registering together.
    start: Barrier,
    registered: AtomicU32,
    stop: AtomicBool,
}

/// What one light actor saw.
#[derive(Default)]
struct ActorLog {
    /// When its first registration was answered.
    registered_at: Option<Instant>,
    /// Connect and the first `Register`, answered (ms).
    register_ms: Option<f64>,
    /// Registrations after a lost session.
    registered_again: u64,
    /// Registration attempts that failed (connection closed or refused, `Register` refused).
    register_failures: u64,
    /// The first failure's reason.
    first_failure: Option<String>,
    /// Per episode: from its first step handed to the sink to the sink's flush (gRPC: the
    /// `PushSteps` acknowledgement; shared memory: the last step in the learner's queue) (ms).
    push_ms: Vec<f64>,
    /// Per episode: `ReportEpisode` answered (ms).
    report_ms: Vec<f64>,
    /// Episodes reported and answered.
    episodes: u64,
    /// Steps handed to the sink.
    sent: u64,
    /// What the learner acknowledged (gRPC), over all sessions.
    tally: Option<SinkTally>,
    /// Assignments cut short: the lease ended, or the learner refused steps or the report.
    leases_lost: u64,
    /// Sessions that ended before the fleet stopped (the actor then registers again, naming
    /// its previous registration, as `adp actor` does).
    sessions_lost: u64,
    /// Why the first of them ended.
    first_loss: Option<String>,
}

/// Milliseconds since `t`.
fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// One registered light actor's connection and credentials.
struct Me {
    control: ControlClient,
    data: proto::grpc::DataClient,
    run: pb::RunRef,
    spec: pb::RunSpec,
    actor_id: u64,
    secret: [u8; 16],
    wire_secret: proto::Bytes,
    /// The observation and action of every synthetic step.
    obs: Vec<f32>,
    action: Vec<f32>,
}

/// A registration the light actor held: its id and secret, sent with the next one.
type Previous = Option<(u64, proto::Bytes)>;

/// Connects and registers `rank` (replacing `previous`), again after each failure (with
/// back-off, up to 5 s) until it is registered or the fleet stops (`None`).
fn register(fleet: &Fleet, rank: u32, previous: &Previous, log: &mut ActorLog) -> anyhow::Result<Option<Me>> {
    let mut wait = Duration::from_millis(200);
    loop {
        let t = Instant::now();
        let answer = fleet.handle.block_on(async {
            let (mut control, data) = fleet.address.connect().await.map_err(|e| e.to_string())?;
            let reply = control
                .register(pb::RegisterRequest {
                    rank,
                    host: proto::hostname(),
                    pid: std::process::id(),
                    actor_kind: "load".into(),
                    previous_actor_id: previous.as_ref().map_or(0, |p| p.0),
                    previous_actor_secret: previous.as_ref().map(|p| p.1.clone()).unwrap_or_default(),
                    ..Default::default()
                })
                .await
                .map_err(|s| format!("Register: {:?}: {}", s.code(), s.message()))?;
            Ok::<_, String>((control, data, reply.into_inner()))
        });
        match answer {
            Ok((control, data, reply)) => {
                if log.registered_at.is_none() {
                    log.register_ms = Some(ms(t));
                    log.registered_at = Some(Instant::now());
                    fleet.registered.fetch_add(1, Ordering::Relaxed);
                } else {
                    log.registered_again += 1;
                }
                let secret = reply.actor_secret[..]
                    .try_into()
                    .map_err(|_| anyhow!("the registration reply has no 16-byte secret"))?;
                let spec = reply.spec.context("the registration reply has no run spec")?;
                return Ok(Some(Me {
                    control,
                    data,
                    run: reply.run.context("the registration reply names no run")?,
                    actor_id: reply.actor_id,
                    secret,
                    wire_secret: reply.actor_secret,
                    obs: vec![0.25; spec.obs_dim as usize],
                    action: vec![0.1; spec.act_dim as usize],
                    spec,
                }));
            }
            Err(why) => {
                log.register_failures += 1;
                log.first_failure.get_or_insert(why);
                if fleet.stop.load(Ordering::Relaxed) {
                    return Ok(None);
                }
                thread::sleep(wait);
                wait = (wait * 2).min(Duration::from_secs(5));
            }
        }
    }
}

/// The step sink and policy source of `me` on the fleet's plane: the real actor's.
fn planes(fleet: &Fleet, rank: u32, me: &Me) -> anyhow::Result<(Box<dyn StepSink>, Box<dyn PolicySource>)> {
    Ok(match fleet.plane {
        LoadPlane::Grpc => (
            Box::new(GrpcStepSink::new(
                fleet.handle.clone(),
                me.data.clone(),
                &me.run.run_id,
                me.run.incarnation,
                Duration::from_secs(60),
            )),
            Box::new(GrpcPolicySource::start(
                &fleet.handle,
                me.data.clone(),
                &me.run.run_id,
                me.run.incarnation,
                me.actor_id,
                &me.secret,
            )),
        ),
        LoadPlane::Shm => {
            // `shm:<prefix>@<host>`, as the learner offers it.
            let prefix = me
                .spec
                .data_plane
                .strip_prefix("shm:")
                .and_then(|s| s.rsplit_once('@'))
                .map(|(prefix, _)| prefix.to_owned())
                .with_context(|| format!("the learner offers `{}`, not shared memory", me.spec.data_plane))?;
            let cfg = ShmConfig {
                service_prefix: prefix,
                max_actors: 1,
                ..ShmConfig::default()
            };
            let node = format!("adp-load-{rank}-{}", std::process::id());
            (
                Box::new(ShmStepSink::open(&cfg, &node)?),
                Box::new(ShmPolicySource::open(&cfg, &node)?),
            )
        }
    })
}

/// Sends one synthetic episode of `steps` steps (the last terminal) through `sink`; returns
/// its checksum.
fn send_episode(
    sink: &mut dyn StepSink,
    header: &LeaseHeader,
    (episode_id, policy_version): (u64, u64),
    steps: u32,
    me: &Me,
) -> Result<u64, PlaneError> {
    let mut checksum = 0u64;
    for step_index in 0..steps {
        let step = StepView {
            episode_id,
            step_index,
            policy_version,
            obs: &me.obs,
            action: &me.action,
            reward: -0.5,
            terminal: step_index + 1 == steps,
            truncated: false,
            final_obs: &[],
        };
        sink.send(header, &step)?;
        checksum = checksum.wrapping_add(step_checksum(&step));
    }
    Ok(checksum)
}

/// Waits, as `adp actor` does, until `policies` has a version of at least `wanted`, the lease
/// ends or the session is gone; returns the newest version received. Looks every 2 ms at
/// first, as `adp actor` does, then less often (up to every 50 ms), so that a thousand waiting
/// threads leave the cores to the learner.
fn await_policy(
    policies: &mut dyn PolicySource,
    have: Option<u64>,
    wanted: u64,
    flags: &Flags,
) -> anyhow::Result<Option<u64>> {
    let mut have = have;
    let mut wait = Duration::from_millis(2);
    while have.is_none_or(|v| v < wanted)
        && !flags.lease_lost.load(Ordering::Acquire)
        && !flags.gone.load(Ordering::Acquire)
    {
        match policies.poll(have)? {
            Some(update) => have = Some(update.version),
            None => {
                thread::sleep(wait);
                wait = (wait * 2).min(Duration::from_millis(50));
            }
        }
    }
    Ok(have)
}

/// One light actor (rank `rank`): registers once the fleet starts, then works assignments
/// until the fleet stops; finishes the assignment it is in, and keeps heartbeating until the
/// learner has finished its lease. A lost session (the connection, a plane or a call failed)
/// is followed by a new registration after a back-off (200 ms, doubling up to 5 s).
fn light_actor(fleet: &Fleet, rank: u32) -> ActorLog {
    let mut log = ActorLog::default();
    fleet.start.wait();
    let mut previous = None;
    let mut wait = Duration::from_millis(200);
    while let Err(e) = session(fleet, rank, &mut previous, &mut log) {
        log.sessions_lost += 1;
        log.first_loss.get_or_insert_with(|| format!("{e:#}"));
        if fleet.stop.load(Ordering::Relaxed) {
            break;
        }
        thread::sleep(wait);
        wait = (wait * 2).min(Duration::from_secs(5));
    }
    log
}

/// One session of [`light_actor`]: registers (replacing `previous`, which becomes this
/// session's registration) and works assignments until the fleet stops (`Ok`) or the session
/// is lost (`Err`).
fn session(fleet: &Fleet, rank: u32, previous: &mut Previous, log: &mut ActorLog) -> anyhow::Result<()> {
    let Some(mut me) = register(fleet, rank, previous, log)? else {
        return Ok(());
    };
    *previous = Some((me.actor_id, me.wire_secret.clone()));
    let (mut sink, mut policies) = planes(fleet, rank, &me)?;
    let flags = Arc::new(Flags::default());
    let ttl = Duration::from_millis(u64::from(me.spec.lease_ttl_ms));
    // `adp actor`'s heartbeat task.
    let _beats = AbortOnDrop(fleet.handle.spawn(heartbeats(
        me.control.clone(),
        me.run.clone(),
        me.actor_id,
        me.wire_secret.clone(),
        Duration::from_millis(u64::from(me.spec.heartbeat_ms.max(10))),
        ttl,
        flags.clone(),
    )));
    let outcome = assignments(fleet, &mut me, sink.as_mut(), policies.as_mut(), &flags, log);
    if let Some(t) = sink.tally() {
        *log.tally.get_or_insert_default() += t;
    }
    // Steps may still wait in the learner's queue (shared memory): the lease stays in the
    // heartbeats until the learner has stored them and finished it, at most a lease TTL.
    let limit = Instant::now() + ttl;
    while outcome.is_ok()
        && flags.lease.load(Ordering::Acquire) != 0
        && !flags.gone.load(Ordering::Acquire)
        && Instant::now() < limit
    {
        thread::sleep(Duration::from_millis(10));
    }
    outcome
}

/// Takes and runs assignments until the fleet stops or the learner says the run is over;
/// `Err` when the session is lost.
fn assignments(
    fleet: &Fleet,
    me: &mut Me,
    sink: &mut dyn StepSink,
    policies: &mut dyn PolicySource,
    flags: &Flags,
    log: &mut ActorLog,
) -> anyhow::Result<()> {
    let mut have = None;
    while !fleet.stop.load(Ordering::Relaxed) && !flags.shutdown.load(Ordering::Acquire) {
        if flags.gone.load(Ordering::Acquire) {
            bail!("the learner no longer knows this session, or stopped answering heartbeats");
        }
        let reply = fleet
            .handle
            .block_on(me.control.next_assignment(pb::AssignmentRequest {
                run: Some(me.run.clone()),
                actor_id: me.actor_id,
                actor_secret: me.wire_secret.clone(),
            }));
        let a = match reply.map(|r| r.into_inner().decision) {
            Ok(Some(pb::assignment_reply::Decision::Assign(a))) => a,
            Ok(Some(pb::assignment_reply::Decision::IdleMs(idle))) => {
                thread::sleep(Duration::from_millis(u64::from(idle.max(1))));
                continue;
            }
            Ok(Some(pb::assignment_reply::Decision::Shutdown(_))) => return Ok(()),
            Ok(None) => bail!("NextAssignment: an empty reply"),
            Err(s) => bail!("NextAssignment: {:?}: {}", s.code(), s.message()),
        };
        flags.lease.store(a.lease_id, Ordering::Release);
        flags.lease_lost.store(false, Ordering::Release);
        have = await_policy(policies, have, a.policy_version, flags)?;
        assignment(fleet, me, &a, have.unwrap_or(0), sink, flags, log)?;
    }
    Ok(())
}

/// Runs assignment `a`'s episodes with policy version `version`, each flushed and reported;
/// stops early when the lease ends or the learner refuses.
fn assignment(
    fleet: &Fleet,
    me: &mut Me,
    a: &pb::Assignment,
    version: u64,
    sink: &mut dyn StepSink,
    flags: &Flags,
    log: &mut ActorLog,
) -> anyhow::Result<()> {
    let header = LeaseHeader {
        incarnation: me.run.incarnation,
        actor_id: me.actor_id,
        lease_id: a.lease_id,
        secret: me.secret,
    };
    let steps = fleet.episode_steps;
    for i in 0..a.episodes {
        if flags.lease_lost.load(Ordering::Acquire) {
            log.leases_lost += 1;
            return Ok(());
        }
        let episode_id = a.first_episode_id + u64::from(i);
        let t = Instant::now();
        let checksum = send_episode(sink, &header, (episode_id, version), steps, me)?;
        log.sent += u64::from(steps);
        match sink.flush() {
            Ok(()) => log.push_ms.push(ms(t)),
            Err(PlaneError::Refused { .. }) => {
                log.leases_lost += 1;
                return Ok(());
            }
            Err(e) => return Err(e.into()),
        }
        let t = Instant::now();
        let report = pb::EpisodeReport {
            run: Some(me.run.clone()),
            actor_id: me.actor_id,
            lease_id: a.lease_id,
            episode_id,
            world: a.world,
            outcome: pb::Outcome::Collision as i32,
            time_s: f64::from(steps) * 0.25,
            episode_return: -0.5 * f64::from(steps),
            steps,
            last_of_assignment: i + 1 == a.episodes,
            steps_checksum: checksum,
            actor_secret: me.wire_secret.clone(),
            policy_version: version,
            ..Default::default()
        };
        match fleet.handle.block_on(me.control.report_episode(report)) {
            Ok(_) => {
                log.report_ms.push(ms(t));
                log.episodes += 1;
            }
            Err(s) if s.code() == tonic::Code::NotFound => {
                log.leases_lost += 1;
                return Ok(());
            }
            Err(s) => bail!("ReportEpisode: {:?}: {}", s.code(), s.message()),
        }
    }
    Ok(())
}

/// The learner child process; killed when dropped.
struct Learner(Child);

impl Drop for Learner {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Learner {
    /// `Err` naming its log when the learner has exited.
    fn alive(&mut self, log: &Path) -> anyhow::Result<()> {
        match self.0.try_wait()? {
            None => Ok(()),
            Some(status) => bail!("the learner exited ({status}); its log is {}", log.display()),
        }
    }

    /// The learner's resident memory now and at its peak (`VmRSS`, `VmHWM`), in MiB.
    fn memory_mib(&self) -> anyhow::Result<(f64, f64)> {
        let path = format!("/proc/{}/status", self.0.id());
        let text = std::fs::read_to_string(&path).with_context(|| format!("cannot read {path}"))?;
        let field = |name: &str| {
            text.lines()
                .find_map(|l| l.strip_prefix(name))
                .and_then(|v| v.split_whitespace().next())
                .and_then(|v| v.parse::<f64>().ok())
                .map(|kib| kib / 1024.0)
                .with_context(|| format!("{path} has no {name}"))
        };
        Ok((field("VmRSS:")?, field("VmHWM:")?))
    }
}

/// `status.json` of `run` and when the learner wrote it (its modification time), read so that
/// both belong to the same write.
fn sample(run: &Path) -> anyhow::Result<(SystemTime, Status)> {
    let path = run.join(learner_service::STATUS_FILE);
    let written = || -> anyhow::Result<SystemTime> {
        std::fs::metadata(&path)
            .and_then(|m| m.modified())
            .with_context(|| format!("cannot read the time of {}", path.display()))
    };
    loop {
        let before = written()?;
        let status = read_status(run)?;
        if written()? == before {
            return Ok((before, status));
        }
    }
}

/// Seconds from `a` to `b`.
fn between(a: SystemTime, b: SystemTime) -> f64 {
    b.duration_since(a).unwrap_or_default().as_secs_f64().max(1e-9)
}

/// Sleeps `d`, failing early when the learner exits.
fn watch(learner: &mut Learner, log: &Path, d: Duration) -> anyhow::Result<()> {
    let end = Instant::now() + d;
    while Instant::now() < end {
        learner.alive(log)?;
        thread::sleep(Duration::from_millis(100).min(end.saturating_duration_since(Instant::now())));
    }
    Ok(())
}

/// The `load` part's figures: starts `adp learner` (the executable `adp`) and `o.actors` light
/// actors on `o.plane`, lets them register, warms up for 10 s, measures for `o.seconds`,
/// stops the actors (each finishes its assignment) and waits until the learner has every step
/// and no lease is open.
pub fn run(adp: &Path, o: &LoadOptions) -> anyhow::Result<Vec<Figure>> {
    if o.actors == 0 || o.episode_steps == 0 {
        bail!("the load part needs at least one actor and one step per episode");
    }
    let dir = tempdir("load")?;
    let run_dir = dir.join("run");
    let cfg = dir.join("load.toml");
    let config = learner_config(o);
    std::fs::write(&cfg, &config).with_context(|| format!("cannot write {}", cfg.display()))?;
    let log = dir.join("learner.log");
    let mut learner = Learner(
        Command::new(adp)
            .args(["learner", "--config"])
            .arg(&cfg)
            .args(["--steps", "1000000000000", "--listen", "127.0.0.1:0", "--out"])
            .arg(&run_dir)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).with_context(|| format!("cannot create {}", log.display()))?)
            .spawn()
            .with_context(|| format!("cannot start {} learner", adp.display()))?,
    );
    eprintln!(
        "load: learner {} in {} with\n{config}",
        learner.0.id(),
        run_dir.display()
    );
    let up = Instant::now() + Duration::from_secs(300);
    while !(run_dir.join(learner_service::ADDR_FILE).is_file() && read_status(&run_dir).is_ok()) {
        learner.alive(&log)?;
        if Instant::now() > up {
            bail!(
                "the learner wrote no address and status in 300 s; its log is {}",
                log.display()
            );
        }
        thread::sleep(Duration::from_millis(100));
    }
    let addr = match o.plane {
        LoadPlane::Grpc => read_addr(&run_dir)?,
        LoadPlane::Shm => format!("unix:{}", run_dir.join(learner_service::SOCKET_FILE).display()),
    };
    let token = proto::auth::read_token_file(&run_dir.join("token"))?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start a tokio runtime")?;
    let fleet = Arc::new(Fleet {
        address: LearnerAddress {
            addr,
            token: Some(token),
            tls: None,
        },
        plane: o.plane,
        episode_steps: o.episode_steps,
        handle: runtime.handle().clone(),
        start: Barrier::new(o.actors as usize + 1),
        registered: AtomicU32::new(0),
        stop: AtomicBool::new(false),
    });
    let actors: Vec<JoinHandle<ActorLog>> = (0..o.actors)
        .map(|rank| {
            let fleet = fleet.clone();
            // The stack of a process's main thread, as `adp actor` has: iceoryx2 needs more
            // than a thread's default 2 MiB.
            thread::Builder::new()
                .name(format!("load-actor-{rank}"))
                .stack_size(8 << 20)
                .spawn(move || light_actor(&fleet, rank))
                .with_context(|| format!("cannot start light actor {rank}"))
        })
        .collect::<anyhow::Result<_>>()?;
    fleet.start.wait();
    let started = Instant::now();
    while fleet.registered.load(Ordering::Relaxed) < o.actors && started.elapsed() < REGISTRATION_PATIENCE {
        watch(&mut learner, &log, Duration::from_millis(50))?;
    }
    eprintln!(
        "load: {} of {} actors registered in {:.1} s",
        fleet.registered.load(Ordering::Relaxed),
        o.actors,
        started.elapsed().as_secs_f64()
    );
    watch(&mut learner, &log, WARMUP)?;
    let (t_a, a) = sample(&run_dir)?;
    let rss_at_start = learner.memory_mib()?.0;
    let window = Duration::from_secs(o.seconds);
    let mut last = (t_a, a.steps_received);
    let opened = Instant::now();
    while opened.elapsed() < window {
        watch(
            &mut learner,
            &log,
            Duration::from_secs(10).min(window.saturating_sub(opened.elapsed())),
        )?;
        let (t, s) = sample(&run_dir)?;
        let (rss, peak) = learner.memory_mib()?;
        eprintln!(
            "load: {:>4.0} s  {:>7.0} steps stored/s  cycle {}  open leases {}  learner {rss:.0} MiB (peak {peak:.0})",
            opened.elapsed().as_secs_f64(),
            (s.steps_received - last.1) as f64 / between(last.0, t),
            s.cycle,
            s.open_leases
        );
        last = (t, s.steps_received);
    }
    let (t_b, b) = sample(&run_dir)?;
    fleet.stop.store(true, Ordering::Relaxed);
    let logs: Vec<ActorLog> = actors
        .into_iter()
        .map(|a| a.join().map_err(|_| anyhow!("a light actor panicked")))
        .collect::<anyhow::Result<_>>()?;
    // Every actor has flushed and reported: wait until the learner has stored what is still
    // queued and finished every lease (the counters stand still over two writes).
    let mut end = sample(&run_dir)?;
    let settled = Instant::now() + Duration::from_secs(120);
    loop {
        watch(&mut learner, &log, Duration::from_millis(500))?;
        let next = sample(&run_dir)?;
        if next.0 != end.0 {
            let still = next.1.steps_received == end.1.steps_received && next.1.episodes == end.1.episodes;
            end = next;
            if still && end.1.open_leases == 0 {
                break;
            }
        }
        if Instant::now() > settled {
            eprintln!("load: the learner still has open leases or moving counters after 120 s");
            break;
        }
    }
    let (rss_end, rss_peak) = learner.memory_mib()?;
    drop(learner);
    drop(runtime);
    let figures = figures(
        o,
        &logs,
        started,
        (t_a, &a),
        (t_b, &b),
        &end.1,
        (rss_at_start, rss_peak, rss_end),
    );
    let _ = std::fs::remove_dir_all(&dir);
    Ok(figures)
}

/// The learner's two status samples of the window, with the times they were written.
type Window<'a> = (SystemTime, &'a Status);

/// The figures of a load run from the actors' logs and the learner's status at the window's
/// ends (`a`, `b`) and after the actors stopped (`end`); `rss` is the learner's resident
/// memory when the window opened, at its peak and at the end (MiB).
fn figures(
    o: &LoadOptions,
    logs: &[ActorLog],
    started: Instant,
    (t_a, a): Window<'_>,
    (t_b, b): Window<'_>,
    end: &Status,
    (rss_start, rss_peak, rss_end): (f64, f64, f64),
) -> Vec<Figure> {
    let n = o.actors;
    let plane = match o.plane {
        LoadPlane::Grpc => "gRPC",
        LoadPlane::Shm => "shared memory",
    };
    let registered: Vec<Instant> = logs.iter().filter_map(|l| l.registered_at).collect();
    let last = registered
        .iter()
        .max()
        .map_or(0.0, |t| t.duration_since(started).as_secs_f64());
    let all = |f: fn(&ActorLog) -> &Vec<f64>| logs.iter().flat_map(f).copied().collect::<Vec<f64>>();
    let (push, report) = (all(|l| &l.push_ms), all(|l| &l.report_ms));
    let register: Vec<f64> = logs.iter().filter_map(|l| l.register_ms).collect();
    let sum = |f: fn(&ActorLog) -> u64| logs.iter().map(f).sum::<u64>();
    let tally = logs
        .iter()
        .filter_map(|l| l.tally)
        .fold(SinkTally::default(), |mut t, l| {
            t += l;
            t
        });
    // What the actors know was stored: acknowledged over gRPC, delivered into the learner's
    // queue over shared memory (which has no acknowledgements).
    let (handed, handed_what) = match o.plane {
        LoadPlane::Grpc => (tally.accepted, "acknowledged as stored"),
        LoadPlane::Shm => (sum(|l| l.sent), "delivered"),
    };
    let failures = sum(|l| l.register_failures);
    let lost = sum(|l| l.sessions_lost);
    if let Some(why) = logs.iter().find_map(|l| l.first_failure.as_deref()) {
        eprintln!("load: {failures} failed registration attempts; the first: {why}");
    }
    if let Some(why) = logs.iter().find_map(|l| l.first_loss.as_deref()) {
        eprintln!("load: {lost} sessions lost; the first: {why}");
    }
    let secs = between(t_a, t_b);
    let refused: u64 = end.refused.iter().map(|r| r.1).sum();
    let (push_what, push_p) = match o.plane {
        LoadPlane::Grpc => ("PushSteps acknowledgement (episode's first step to Ack)", "ms"),
        LoadPlane::Shm => (
            "episode delivery into the learner's queue (no acknowledgement)",
            "ms",
        ),
    };
    let mut f = vec![
        figure(
            format!("{n} light actors over {plane}: registered"),
            registered.len() as f64,
            "",
        )
        .exactly(f64::from(n)),
        figure(
            "registrations/s (connect + Register, all actors at once)",
            registered.len() as f64 / last.max(1e-9),
            "1/s",
        ),
        figure(
            "Register p50 (connect + call)",
            percentile(register.clone(), 0.5),
            "ms",
        ),
        figure("Register p99 (connect + call)", percentile(register, 0.99), "ms"),
        figure("failed registration attempts", failures as f64, "").exactly(0.0),
        figure(
            format!(
                "steps stored/s ({:.0} s window, {} steps per episode)",
                secs, o.episode_steps
            ),
            (b.steps_received - a.steps_received) as f64 / secs,
            "1/s",
        ),
        figure(
            "episodes reported/s",
            (b.episodes - a.episodes) as f64 / secs,
            "1/s",
        ),
        figure(format!("{push_what} p50"), percentile(push.clone(), 0.5), push_p),
        figure(format!("{push_what} p99"), percentile(push, 0.99), push_p),
        figure("ReportEpisode p50", percentile(report.clone(), 0.5), "ms"),
        figure("ReportEpisode p99", percentile(report, 0.99), "ms"),
        figure("learner resident memory, window opening", rss_start, "MiB"),
        figure("learner resident memory, peak", rss_peak, "MiB"),
        figure("learner resident memory, end", rss_end, "MiB"),
        figure(
            "steps stored by the learner (status.json)",
            end.steps_received as f64,
            "",
        ),
        figure(
            format!("stored − {handed_what} by the actors' sinks (nothing lost: 0)"),
            end.steps_received as f64 - handed as f64,
            "",
        )
        .exactly(0.0),
        figure("steps refused by the learner", refused as f64, "").exactly(0.0),
        figure(
            "episodes reported − verified by the learner (0)",
            sum(|l| l.episodes) as f64 - end.episodes_verified as f64,
            "",
        )
        .exactly(0.0),
        figure(
            "episodes mismatched or abandoned",
            (end.episodes_mismatched + end.episodes_abandoned) as f64,
            "",
        )
        .exactly(0.0),
        figure(
            "leases expired, dropped or cut",
            (end.leases_expired + end.leases_dropped + end.leases_cut) as f64,
            "",
        )
        .exactly(0.0),
        figure(
            "assignments cut short (lease ended, steps refused)",
            sum(|l| l.leases_lost) as f64,
            "",
        )
        .exactly(0.0),
        figure(
            "connections refused per address or closed for room (learner)",
            (end.connections.refused_per_address + end.connections.closed_for_room) as f64,
            "",
        ),
        figure(
            "registrations refused per address (learner)",
            end.connections.registrations_refused_per_address as f64,
            "",
        ),
        figure(
            "policy streams refused, per address or in all (learner)",
            (end.connections.policy_streams_refused_per_address + end.connections.policy_streams_refused)
                as f64,
            "",
        ),
        figure("sessions lost (the actor registered again)", lost as f64, "").exactly(0.0),
        figure(
            "registrations after a lost session",
            sum(|l| l.registered_again) as f64,
            "",
        ),
    ];
    if o.plane == LoadPlane::Grpc {
        f.push(
            figure(
                "steps sent − acknowledged (accepted, duplicate or refused)",
                tally.sent as f64 - (tally.accepted + tally.duplicates + tally.refused) as f64,
                "",
            )
            .exactly(0.0),
        );
    }
    f
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The learner configuration the bench writes is a valid run configuration, raises every
    /// cap a fleet of that size reaches (and none below its default), and leaves them alone
    /// with `default_limits`.
    #[test]
    fn the_learner_config_raises_every_cap_to_the_actor_count() {
        let o = LoadOptions {
            actors: 1024,
            plane: LoadPlane::Shm,
            seconds: 1,
            episode_steps: 100,
            default_limits: false,
        };
        let cfg = train_config::TrainConfig::parse("load", &learner_config(&o)).unwrap();
        let s = cfg.service;
        assert!(s.shared_memory && !s.ddp_init);
        assert_eq!(
            (
                s.max_connections_per_ip,
                s.registrations_per_ip,
                s.policy_streams_per_ip
            ),
            (1024, 1024, 1024)
        );
        assert_eq!(
            (s.max_connections, s.max_policy_streams, s.shm_max_actors),
            (1024, 1024, 1024)
        );
        assert!(cfg.td3.warmup_steps > 1 << 29, "no TD3 updates");
        let few = train_config::TrainConfig::parse(
            "load",
            &learner_config(&LoadOptions {
                actors: 8,
                ..o.clone()
            }),
        )
        .unwrap()
        .service;
        assert_eq!((few.max_connections, few.registrations_per_ip), (1024, 256));
        let defaults = LoadOptions {
            default_limits: true,
            plane: LoadPlane::Grpc,
            ..o
        };
        let s = train_config::TrainConfig::parse("load", &learner_config(&defaults))
            .unwrap()
            .service;
        assert!(!s.shared_memory);
        assert_eq!(
            (s.max_connections_per_ip, s.registrations_per_ip),
            (
                ServiceConfig::default().max_connections_per_ip,
                ServiceConfig::default().registrations_per_ip
            )
        );
    }
}
