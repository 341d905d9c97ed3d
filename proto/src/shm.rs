//! The shared-memory data plane (iceoryx2 0.10 publish/subscribe), used when an actor and the
//! learner run on the same node.
//!
//! Two services per learner incarnation, named under [`ShmConfig::service_prefix`]:
//!
//! - `<prefix>/steps`: every actor publishes its step records; the learner is the only
//!   subscriber. Lossless: safe overflow is off and publishers use
//!   [`BackpressureStrategy::RetryUntilDelivered`], so an actor blocks while the learner's
//!   queue for it ([`ShmConfig::queue_depth`] records) is full. That blocking is the learner's
//!   rate limiter's back-pressure. A record is written in place into a fixed-size slot of the
//!   actor's shared memory ([`MAX_STEP_FLOATS`] floats) and read in place by the learner.
//! - `<prefix>/policy`: the learner publishes policy versions; every actor subscribes.
//!   Latest wins: safe overflow is on, each subscriber buffers one version and the service
//!   keeps a history of one, so an actor that connects late still receives the newest version.
//!
//! Actor side: [`ShmStepSink`] and [`ShmPolicySource`] implement the plane traits of
//! [`crate::plane`]. Learner side: [`ShmStepSource`] and [`ShmPolicyPublisher`].
//!
//! Both sides must use the same [`ShmConfig`] (the learner hands its settings to the actors):
//! service settings are fixed by whichever side creates the service first, and a side that
//! asks for more (a deeper queue, more actors) cannot open it.
//!
//! Nodes are created with iceoryx2's signal handling disabled (the process keeps its own
//! SIGINT/SIGTERM behaviour). Shared-memory segments live in `/dev/shm` (prefix `iox2_`),
//! management files under the iceoryx2 root path (`/tmp/iceoryx2/` unless
//! [`ShmConfig::root`] says otherwise); a node removes its files when dropped, and the files
//! of processes that died are removed by the next node that is created, by the learner's
//! policy publisher (every half second) or by a sink that looks for its learner (see
//! [`ShmStepSink::send`]). A process looks for dead nodes at most once per half second
//! (a look lists every node), not at every episode, node or service opening.

use std::os::unix::ffi::OsStrExt;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::port::{BackpressureAction, BackpressureInfo};
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubService;
use thiserror::Error;

use crate::plane::{LeaseHeader, PlaneError, PolicySource, PolicyUpdate, SinkTally, StepSink};
use crate::validate::StepView;

/// The iceoryx2 service flavour: inter-process, ports usable from any thread (`Send`).
type Ipc = ipc_threadsafe::Service;

/// Floats in one step slot: observation, action and (for a truncated step) final observation
/// together. 1536 holds the largest run (746 + 20 + 746).
pub const MAX_STEP_FLOATS: usize = 1536;

/// How long a blocked sink waits between two looks for a dead learner.
const LIVENESS_PERIOD: Duration = Duration::from_millis(500);

/// How often the policy publisher connects new subscribers and hands them the latest version.
const POLICY_REFRESH_PERIOD: Duration = Duration::from_millis(20);

/// Policy chunks the learner's segment holds: the latest version (kept as history and in every
/// subscriber's one-slot buffer), the one being written, and older versions still being
/// copied by actors.
const POLICY_CHUNKS: usize = 8;

/// Where iceoryx2 keeps its data segments on Linux (POSIX shared memory, a tmpfs).
const SEGMENT_DIR: &str = "/dev/shm";

/// Step records an actor's segment holds beyond the learner's queue (loans, in flight).
const STEP_SLACK: usize = 8;

/// [`SlotHead::flags`] bit: a true end of the episode.
const TERMINAL: u32 = 1;
/// [`SlotHead::flags`] bit: a time-limit end (`final_obs` follows the action).
const TRUNCATED: u32 = 2;

/// Settings of the shared-memory plane. Plain data; both sides must use equal values.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShmConfig {
    /// Prefix of the service names, e.g. `adp/<run_id>/<incarnation>`: a new learner
    /// incarnation gets fresh services.
    pub service_prefix: String,
    /// Most actors (step publishers, policy subscribers) at once. Default 256.
    pub max_actors: usize,
    /// Step records the learner buffers per actor before that actor blocks. Default 256.
    pub queue_depth: usize,
    /// Largest policy (flat weights) the learner can publish. Default 2^20 floats (4 MiB).
    pub max_policy_floats: usize,
    /// iceoryx2 root path for its management files (isolates tests); `None` = iceoryx2's
    /// default, `/tmp/iceoryx2/`. (iceoryx2 configuration files are not read: every setting
    /// that matters is made here.)
    pub root: Option<PathBuf>,
}

impl Default for ShmConfig {
    fn default() -> Self {
        Self {
            service_prefix: "adp".into(),
            max_actors: 256,
            queue_depth: 256,
            max_policy_floats: 1 << 20,
            root: None,
        }
    }
}

impl ShmConfig {
    fn iceoryx(&self) -> Result<Config, ShmError> {
        let mut config = Config::default();
        // Dead nodes are looked for by `remove_dead_nodes`, at most once per period per
        // process, not by iceoryx2 at every node creation, node drop and service opening.
        config.global.node.cleanup_dead_nodes_on_creation = false;
        config.global.node.cleanup_dead_nodes_on_destruction = false;
        config.global.service.cleanup_dead_nodes_on_open = false;
        if let Some(root) = &self.root {
            let path = Path::new(root.as_os_str().as_bytes()).map_err(|e| ShmError::Setup {
                what: root.display().to_string(),
                op: "use as the iceoryx2 root path",
                detail: format!("{e:?}"),
            })?;
            config.global.set_root_path(&path);
        }
        Ok(config)
    }

    fn service(&self, leaf: &str) -> Result<(ServiceName, String), ShmError> {
        let label = format!("{}/{leaf}", self.service_prefix);
        let name = ServiceName::new(&label).map_err(|e| ShmError::Setup {
            what: label.clone(),
            op: "use as a service name",
            detail: format!("{e:?}"),
        })?;
        Ok((name, label))
    }

    /// The iceoryx2 configuration of this run and a node called `name` under it.
    fn node(&self, name: &str) -> Result<(Config, Node<Ipc>), ShmError> {
        let config = self.iceoryx()?;
        let setup = |op, detail| ShmError::Setup {
            what: format!("node `{name}`"),
            op,
            detail,
        };
        let node_name = NodeName::new(name).map_err(|e| setup("use as a node name", format!("{e:?}")))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .map_err(|e| setup("create", e.to_string()))?;
        // Frees the ports of dead processes before this node opens its service.
        remove_dead_nodes(&config);
        Ok((config, node))
    }

    fn steps(&self, node: &Node<Ipc>) -> Result<(StepService, String), ShmError> {
        let (name, label) = self.service("steps")?;
        let service = node
            .service_builder(&name)
            .publish_subscribe::<StepSlot>()
            .enable_safe_overflow(false)
            .subscriber_max_buffer_size(self.queue_depth)
            .history_size(0)
            .max_publishers(self.max_actors)
            .max_subscribers(1)
            .max_nodes(self.max_actors + 8)
            .open_or_create()
            .map_err(|e| setup_error(&label, "open or create the service", e))?;
        Ok((service, label))
    }

    fn policy(&self, node: &Node<Ipc>) -> Result<(PolicyService, String), ShmError> {
        let (name, label) = self.service("policy")?;
        let service = node
            .service_builder(&name)
            .publish_subscribe::<[f32]>()
            .user_header::<PolicyHead>()
            .enable_safe_overflow(true)
            .subscriber_max_buffer_size(1)
            .history_size(1)
            .max_publishers(1)
            .max_subscribers(self.max_actors)
            .max_nodes(self.max_actors + 8)
            .open_or_create()
            .map_err(|e| setup_error(&label, "open or create the service", e))?;
        Ok((service, label))
    }
}

/// A failure of the shared-memory plane, naming the service (or node, path) and the operation.
#[derive(Debug, Error)]
pub enum ShmError {
    /// Creating a node, service or port failed.
    #[error("shared memory `{what}`: cannot {op}: {detail}")]
    Setup {
        /// The node, service or path.
        what: String,
        /// The operation.
        op: &'static str,
        /// iceoryx2's error.
        detail: String,
    },
    /// Loaning, sending or receiving on an open port failed.
    #[error("shared-memory service `{service}`: {op} failed: {detail}")]
    Transfer {
        /// The service.
        service: String,
        /// The operation.
        op: &'static str,
        /// iceoryx2's error.
        detail: String,
    },
    /// A message is larger than the service's slots.
    #[error("shared-memory service `{service}`: {what} has {got} floats, at most {limit} fit")]
    TooLarge {
        /// The service.
        service: String,
        /// The message.
        what: &'static str,
        /// Its size.
        got: usize,
        /// The limit.
        limit: usize,
    },
}

impl From<ShmError> for PlaneError {
    fn from(e: ShmError) -> Self {
        let plane = "shm";
        match e {
            ShmError::Setup { .. } => PlaneError::Setup {
                plane,
                detail: e.to_string(),
            },
            ShmError::Transfer { .. } => PlaneError::Disconnected {
                plane,
                detail: e.to_string(),
            },
            ShmError::TooLarge { .. } => PlaneError::TooLarge {
                plane,
                detail: e.to_string(),
            },
        }
    }
}

/// Refuses a data segment of `bytes` for `what` when the shared-memory filesystem has less
/// room left. tmpfs gives a segment its pages only when they are first written, so a segment
/// larger than the room left is created without complaint and its writer later dies of
/// SIGBUS; this check turns that into an error at opening, which callers degrade to gRPC.
/// It sees the room left now, not what other segments created earlier may still claim. When
/// the filesystem cannot be inspected, the opening goes ahead.
fn ensure_room(bytes: u64, what: &str) -> Result<(), ShmError> {
    let Some(free) = free_bytes(SEGMENT_DIR) else {
        return Ok(());
    };
    if free >= bytes {
        return Ok(());
    }
    Err(ShmError::Setup {
        what: what.to_owned(),
        op: "reserve room in /dev/shm",
        detail: format!(
            "the segment needs {:.1} MiB, {SEGMENT_DIR} has {:.1} MiB free",
            bytes as f64 / MIB,
            free as f64 / MIB
        ),
    })
}

const MIB: f64 = 1024.0 * 1024.0;

/// Bytes an unprivileged writer may still use on the filesystem of `dir`.
fn free_bytes(dir: &str) -> Option<u64> {
    let path = std::ffi::CString::new(dir).ok()?;
    let mut st = std::mem::MaybeUninit::<libc::statvfs>::uninit();
    // SAFETY: `path` is a valid C string and `st` has room for one `statvfs`, which the call
    // fills when it returns 0.
    if unsafe { libc::statvfs(path.as_ptr(), st.as_mut_ptr()) } != 0 {
        return None;
    }
    // SAFETY: the call returned 0, so it initialized `st`.
    let st = unsafe { st.assume_init() };
    Some(st.f_bavail.saturating_mul(st.f_frsize))
}

fn setup_error(what: &str, op: &'static str, e: impl std::fmt::Display) -> ShmError {
    ShmError::Setup {
        what: what.to_owned(),
        op,
        detail: e.to_string(),
    }
}

fn transfer_error(service: &str, op: &'static str, e: impl std::fmt::Display) -> ShmError {
    ShmError::Transfer {
        service: service.to_owned(),
        op,
        detail: e.to_string(),
    }
}

/// The fixed part of a step slot. Integers and floats only, so any bytes an actor writes are
/// a valid value.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("adp.shm.SlotHead.v2")]
struct SlotHead {
    incarnation: u64,
    actor_id: u64,
    lease_id: u64,
    secret: [u8; 16],
    episode_id: u64,
    policy_version: u64,
    step_index: u32,
    reward: f32,
    flags: u32,
    obs_len: u32,
    act_len: u32,
    final_len: u32,
}

/// One step record in shared memory: the head, then `obs`, `action` and `final_obs` back to
/// back in `data` (the rest zero).
#[repr(C)]
#[derive(Debug, ZeroCopySend)]
#[type_name("adp.shm.StepSlot.v2")]
struct StepSlot {
    head: SlotHead,
    data: [f32; MAX_STEP_FLOATS],
}

type StepService = PubSubService<Ipc, StepSlot, ()>;

/// Writes a whole slot in place: `head`, the parts back to back, zeros after them.
///
/// Panics if the parts do not fit (callers check first).
fn fill_slot(slot: &mut std::mem::MaybeUninit<StepSlot>, head: SlotHead, parts: [&[f32]; 3]) {
    let used: usize = parts.iter().map(|p| p.len()).sum();
    assert!(
        used <= MAX_STEP_FLOATS,
        "step parts of {used} floats exceed the slot"
    );
    let slot = slot.as_mut_ptr();
    // SAFETY: `slot` points to memory for one `StepSlot` that we may write. Each copy stays
    // inside `data` (`used <= MAX_STEP_FLOATS`) and the sources are the callers' slices, which
    // cannot overlap the freshly loaned slot.
    unsafe {
        (&raw mut (*slot).head).write(head);
        let data = (&raw mut (*slot).data).cast::<f32>();
        let mut at = 0;
        for part in parts {
            std::ptr::copy_nonoverlapping(part.as_ptr(), data.add(at), part.len());
            at += part.len();
        }
        std::ptr::write_bytes(data.add(at), 0, MAX_STEP_FLOATS - at);
    }
}

/// The record in `slot` as the plane traits see it. A head whose lengths do not fit the slot
/// (only a broken or hostile actor writes one) yields empty `obs`, `action` and `final_obs`,
/// which [`crate::validate::Validator::check_step`] refuses as a shape error on `obs`.
fn read_slot(slot: &StepSlot) -> (LeaseHeader, StepView<'_>) {
    let h = &slot.head;
    let (o, a, f) = (h.obs_len as usize, h.act_len as usize, h.final_len as usize);
    let (obs, action, final_obs): (&[f32], &[f32], &[f32]) = if o + a + f <= MAX_STEP_FLOATS {
        let (obs, rest) = slot.data.split_at(o);
        let (action, rest) = rest.split_at(a);
        (obs, action, &rest[..f])
    } else {
        (&[], &[], &[])
    };
    let lease = LeaseHeader {
        incarnation: h.incarnation,
        actor_id: h.actor_id,
        lease_id: h.lease_id,
        secret: h.secret,
    };
    let step = StepView {
        episode_id: h.episode_id,
        step_index: h.step_index,
        policy_version: h.policy_version,
        obs,
        action,
        reward: h.reward,
        terminal: h.flags & TERMINAL != 0,
        truncated: h.flags & TRUNCATED != 0,
        final_obs,
    };
    (lease, step)
}

/// Removes the resources of every iceoryx2 node under `config` whose process died, so that
/// they stop holding ports and stop counting as connected: a killed learner's subscriber (a
/// sink then reports [`PlaneError::Disconnected`] instead of waiting forever), or a killed
/// actor's publisher and subscriber (their port slots, [`ShmConfig::max_actors`], are free
/// again). Best effort: a node that cannot be removed now stays for the next look.
///
/// A look lists every node under the root and parses each one's details file, so its cost
/// grows with the number of nodes (two per actor). One process therefore looks at most once
/// per [`DEAD_NODE_SCAN_PERIOD`] per root path, whichever of its threads and ports asks
/// ([`scan_due`]); a caller that finds a look done recently, or one running, returns at once.
/// iceoryx2's own looks (at every node creation and drop and every service opening) are
/// switched off in [`ShmConfig::iceoryx`] for the same reason: with a thousand actors they
/// made starting the actors quadratic.
fn remove_dead_nodes(config: &Config) {
    if !scan_due(config.global.root_path().as_bytes(), Instant::now()) {
        return;
    }
    // A listing failure leaves everything as it was; the caller's next look retries.
    let _ = Node::<Ipc>::list(config, |state| {
        if let NodeState::Dead(node) = state {
            // Another process may be removing the same node; either way it goes.
            let _ = node.try_remove_stale_resources();
        }
        CallbackProgression::Continue
    });
}

/// The least time between two looks for dead nodes under one root path in one process.
const DEAD_NODE_SCAN_PERIOD: Duration = Duration::from_millis(500);

/// When this process last looked for dead nodes, per iceoryx2 root path.
static LAST_SCAN: Mutex<Vec<(Vec<u8>, Instant)>> = Mutex::new(Vec::new());

/// Whether a look for dead nodes under `root` is due at `now` (none in this process within
/// [`DEAD_NODE_SCAN_PERIOD`]); if so, records `now` as the last look. `false` while another
/// thread holds the record (it is deciding or has just decided to look).
fn scan_due(root: &[u8], now: Instant) -> bool {
    let Ok(mut last) = LAST_SCAN.try_lock() else {
        return false;
    };
    match last.iter_mut().find(|(r, _)| r == root) {
        Some((_, at)) if now.saturating_duration_since(*at) < DEAD_NODE_SCAN_PERIOD => false,
        Some((_, at)) => {
            *at = now;
            true
        }
        None => {
            last.push((root.to_vec(), now));
            true
        }
    }
}

/// `Debug` for the port wrappers: the type's name and its service label.
macro_rules! debug_by_label {
    ($($port:ident),*) => {$(
        impl std::fmt::Debug for $port {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.debug_struct(stringify!($port))
                    .field("service", &self.label)
                    .finish()
            }
        }
    )*};
}

debug_by_label!(ShmStepSink, ShmStepSource, ShmPolicyPublisher, ShmPolicySource);

/// The actor's end of the step service (`<prefix>/steps`).
///
/// [`StepSink::send`] writes the record straight into a slot of the actor's shared memory (one
/// copy of each slice, no allocation) and hands it to the learner's queue, blocking while that
/// queue is full. `Send`; one thread uses it at a time (`&mut self`).
pub struct ShmStepSink {
    publisher: Publisher<Ipc, StepSlot, ()>,
    service: StepService,
    config: Config,
    label: String,
}

impl ShmStepSink {
    /// Opens (or creates, with the same settings the learner uses) the step service of `cfg`
    /// through a new node called `node_name`, and a publisher on it.
    /// Fails before creating anything when `/dev/shm` has no room for the sink's segment
    /// ([`ShmConfig::queue_depth`] step records and a few more).
    pub fn open(cfg: &ShmConfig, node_name: &str) -> Result<Self, PlaneError> {
        let bytes = (cfg.queue_depth + STEP_SLACK) * std::mem::size_of::<StepSlot>();
        ensure_room(bytes as u64, &format!("{}/steps", cfg.service_prefix))?;
        let (config, node) = cfg.node(node_name)?;
        let (service, label) = cfg.steps(&node)?;
        let publisher = service
            .publisher_builder()
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .set_backpressure_handler(learner_watch(config.clone()))
            .create()
            .map_err(|e| setup_error(&label, "create a publisher", e))?;
        Ok(Self {
            publisher,
            service,
            config,
            label,
        })
    }

    /// `Ok` while a learner subscribes to the service, after removing the subscriptions of
    /// learners whose process died.
    fn learner_present(&self) -> Result<(), PlaneError> {
        remove_dead_nodes(&self.config);
        if self.service.dynamic_config().number_of_subscribers() == 0 {
            return Err(PlaneError::Disconnected {
                plane: "shm",
                detail: format!("no learner subscribes to `{}` (it exited or died)", self.label),
            });
        }
        Ok(())
    }
}

/// The back-pressure handler of a step publisher: keeps retrying (lossless), but every
/// [`LIVENESS_PERIOD`] of one blocked delivery removes dead nodes, so that a learner killed
/// while this actor waits on its full queue stops counting as connected and the delivery
/// ends (with no recipient, which [`ShmStepSink::send`] reports).
fn learner_watch(config: Config) -> impl Fn(&BackpressureInfo) -> BackpressureAction + Send {
    let looks = AtomicU64::new(0);
    move |info| {
        if info.retries == 0 {
            looks.store(0, Ordering::Relaxed);
        }
        let due = (info.elapsed_time.as_millis() / LIVENESS_PERIOD.as_millis()) as u64;
        if due > looks.load(Ordering::Relaxed) {
            looks.store(due, Ordering::Relaxed);
            remove_dead_nodes(&config);
        }
        BackpressureAction::Retry
    }
}

impl StepSink for ShmStepSink {
    /// Writes the record into a shared-memory slot and delivers it to the learner's queue.
    ///
    /// Blocks while the learner's queue for this actor is full (its rate limiter). A record
    /// longer than [`MAX_STEP_FLOATS`] in total is [`PlaneError::TooLarge`]. If the learner
    /// subscription is gone (the learner exited, or its process died: dead nodes are removed
    /// here and, while blocked, every half second) the record is not delivered and the result
    /// is [`PlaneError::Disconnected`]. While the learner is alive but has not yet attached
    /// to this actor's connection, the record is re-sent with a short back-off.
    fn send(&mut self, header: &LeaseHeader, step: &StepView<'_>) -> Result<(), PlaneError> {
        let (o, a, f) = (step.obs.len(), step.action.len(), step.final_obs.len());
        if o + a + f > MAX_STEP_FLOATS {
            return Err(ShmError::TooLarge {
                service: self.label.clone(),
                what: "step record (obs + action + final_obs)",
                got: o + a + f,
                limit: MAX_STEP_FLOATS,
            }
            .into());
        }
        let head = SlotHead {
            incarnation: header.incarnation,
            actor_id: header.actor_id,
            lease_id: header.lease_id,
            secret: header.secret,
            episode_id: step.episode_id,
            policy_version: step.policy_version,
            step_index: step.step_index,
            reward: step.reward,
            flags: if step.terminal { TERMINAL } else { 0 } | if step.truncated { TRUNCATED } else { 0 },
            obs_len: o as u32,
            act_len: a as u32,
            final_len: f as u32,
        };
        let mut backoff = Duration::from_micros(50);
        loop {
            let mut sample = self
                .publisher
                .loan_uninit()
                .map_err(|e| transfer_error(&self.label, "loan a step slot", e))?;
            fill_slot(
                sample.payload_mut(),
                head,
                [step.obs, step.action, step.final_obs],
            );
            // SAFETY: `fill_slot` wrote every byte of the slot (head, parts, zero tail).
            let sample = unsafe { sample.assume_init() };
            let delivered = sample
                .send()
                .map_err(|e| transfer_error(&self.label, "send a step record", e))?;
            if delivered > 0 {
                return Ok(());
            }
            self.learner_present()?;
            thread::sleep(backoff);
            backoff = (backoff * 2).min(Duration::from_millis(5));
        }
    }

    /// A successful [`send`](StepSink::send) has already put the record into the learner's
    /// queue, so this only checks that the learner still subscribes:
    /// [`PlaneError::Disconnected`] if it exited or died.
    fn flush(&mut self) -> Result<(), PlaneError> {
        self.learner_present()
    }

    /// Shared memory carries no acknowledgements: `None`.
    fn tally(&self) -> Option<SinkTally> {
        None
    }
}

/// The learner's end of the step service (`<prefix>/steps`): one subscriber with a queue of
/// [`ShmConfig::queue_depth`] records per actor. `Send`; one thread drains it at a time.
pub struct ShmStepSource {
    subscriber: Subscriber<Ipc, StepSlot, ()>,
    label: String,
}

impl ShmStepSource {
    /// Creates (or opens) the step service of `cfg` and subscribes to it, through a node
    /// called `adp-learner`. Only one source may exist per service.
    pub fn open(cfg: &ShmConfig) -> Result<Self, ShmError> {
        let (_, node) = cfg.node("adp-learner")?;
        let (service, label) = cfg.steps(&node)?;
        let subscriber = service
            .subscriber_builder()
            .create()
            .map_err(|e| setup_error(&label, "create the subscriber", e))?;
        Ok(Self { subscriber, label })
    }

    /// Receives up to `max` step records that are waiting (does not wait for more) and calls
    /// `f` with each, in order per actor. Returns how many.
    ///
    /// The views borrow the actor's shared memory directly (no copy); the slot goes back to
    /// the actor when `f` returns. Nothing in a record is trusted: lengths that do not fit the
    /// slot give empty slices (refused by [`crate::validate::Validator::check_step`] as a
    /// shape error on `obs`), and everything else must pass that validator and the learner's
    /// admission like gRPC records. A hostile actor process can still rewrite a slot while
    /// `f` reads it, so `f` should copy first and validate the copy before it is used.
    pub fn drain(
        &mut self,
        max: usize,
        mut f: impl FnMut(&LeaseHeader, &StepView<'_>),
    ) -> Result<usize, ShmError> {
        let mut n = 0;
        while n < max {
            let Some(sample) = self
                .subscriber
                .receive()
                .map_err(|e| transfer_error(&self.label, "receive a step record", e))?
            else {
                break;
            };
            let (lease, step) = read_slot(sample.payload());
            f(&lease, &step);
            n += 1;
        }
        Ok(n)
    }
}

/// The user header of a policy sample.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, ZeroCopySend)]
#[type_name("adp.shm.PolicyHead.v1")]
struct PolicyHead {
    version: u64,
    exploration_sigma: f64,
}

type PolicyService = PubSubService<Ipc, [f32], PolicyHead>;
type PolicyPort = Publisher<Ipc, [f32], PolicyHead>;

/// The learner's end of the policy service (`<prefix>/policy`).
///
/// A background thread (`adp-shm-policy`) connects actors that subscribe later every 20 ms
/// and hands them the latest version; it also removes the nodes of dead processes (at most
/// twice a second), which frees the port slots of killed actors. `Send`; one thread publishes
/// at a time (`&mut self`).
/// Dropping it stops that thread.
pub struct ShmPolicyPublisher {
    publisher: Arc<PolicyPort>,
    stop: Option<mpsc::Sender<()>>,
    refresher: Option<JoinHandle<()>>,
    max_floats: usize,
    label: String,
}

impl ShmPolicyPublisher {
    /// Creates (or opens) the policy service of `cfg` through a node called
    /// `adp-learner-policy`, a publisher for policies of up to
    /// [`ShmConfig::max_policy_floats`] floats, and its refresh thread.
    /// Fails before creating anything when `/dev/shm` has no room for the publisher's segment
    /// (a few policies of [`ShmConfig::max_policy_floats`]).
    pub fn open(cfg: &ShmConfig) -> Result<Self, ShmError> {
        let bytes = POLICY_CHUNKS * cfg.max_policy_floats * std::mem::size_of::<f32>();
        ensure_room(bytes as u64, &format!("{}/policy", cfg.service_prefix))?;
        let (config, node) = cfg.node("adp-learner-policy")?;
        let (service, label) = cfg.policy(&node)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(cfg.max_policy_floats)
            .allocation_strategy(AllocationStrategy::Static)
            .max_loaned_samples(1)
            .override_sample_preallocation(|_| POLICY_CHUNKS)
            .create()
            .map_err(|e| setup_error(&label, "create the publisher", e))?;
        let publisher = Arc::new(publisher);
        let (stop, stopped) = mpsc::channel::<()>();
        let port = Arc::clone(&publisher);
        let refresher = thread::Builder::new()
            .name("adp-shm-policy".into())
            .spawn(move || {
                while let Err(mpsc::RecvTimeoutError::Timeout) = stopped.recv_timeout(POLICY_REFRESH_PERIOD) {
                    // Frees the ports of actors whose process died (at most every
                    // `DEAD_NODE_SCAN_PERIOD`), so that actors replacing them can open.
                    remove_dead_nodes(&config);
                    // A subscriber that cannot be connected now (e.g. a dying actor) is retried
                    // on the next round; iceoryx2 logs the failure.
                    let _ = port.update_connections();
                }
            })
            .map_err(|e| setup_error(&label, "start the policy refresh thread", e))?;
        Ok(Self {
            publisher,
            stop: Some(stop),
            refresher: Some(refresher),
            max_floats: cfg.max_policy_floats,
            label,
        })
    }

    /// Publishes a policy version: the weights are copied once into shared memory, every
    /// connected actor's one-slot buffer then holds it (replacing an older version it did not
    /// poll), and actors that connect later receive it too. Versions should increase.
    ///
    /// Weights longer than [`ShmConfig::max_policy_floats`] are [`ShmError::TooLarge`]; a
    /// full segment (more than a few older versions still being copied by actors) is a
    /// [`ShmError::Transfer`] error and the caller may publish again later.
    pub fn publish(&mut self, version: u64, sigma: f64, weights: &[f32]) -> Result<(), ShmError> {
        if weights.len() > self.max_floats {
            return Err(ShmError::TooLarge {
                service: self.label.clone(),
                what: "policy weights",
                got: weights.len(),
                limit: self.max_floats,
            });
        }
        let mut sample = self
            .publisher
            .loan_slice_uninit(weights.len())
            .map_err(|e| transfer_error(&self.label, "loan a policy sample", e))?;
        *sample.user_header_mut() = PolicyHead {
            version,
            exploration_sigma: sigma,
        };
        sample
            .write_from_slice(weights)
            .send()
            .map_err(|e| transfer_error(&self.label, "send a policy", e))?;
        Ok(())
    }
}

impl Drop for ShmPolicyPublisher {
    fn drop(&mut self) {
        drop(self.stop.take());
        if let Some(refresher) = self.refresher.take() {
            // The thread only sleeps and refreshes; a panic there has nothing left to report.
            let _ = refresher.join();
        }
    }
}

/// The actor's end of the policy service (`<prefix>/policy`). `Send`; one thread polls it at
/// a time (`&mut self`).
pub struct ShmPolicySource {
    subscriber: Subscriber<Ipc, [f32], PolicyHead>,
    label: String,
}

impl ShmPolicySource {
    /// Opens (or creates, with the learner's settings) the policy service of `cfg` through a
    /// new node called `node_name`, and subscribes to it. The learner's publisher hands the
    /// latest version to a new subscriber within about 20 ms.
    pub fn open(cfg: &ShmConfig, node_name: &str) -> Result<Self, PlaneError> {
        let (_, node) = cfg.node(node_name)?;
        let (service, label) = cfg.policy(&node)?;
        let subscriber = service
            .subscriber_builder()
            .create()
            .map_err(|e| setup_error(&label, "create a subscriber", e))?;
        Ok(Self { subscriber, label })
    }
}

impl PolicySource for ShmPolicySource {
    /// Takes every waiting version (at most one: the buffer keeps the newest), and returns the
    /// newest if it is newer than `have`; the weights are copied out of shared memory.
    fn poll(&mut self, have: Option<u64>) -> Result<Option<PolicyUpdate>, PlaneError> {
        let mut newest: Option<Sample<Ipc, [f32], PolicyHead>> = None;
        while let Some(sample) = self
            .subscriber
            .receive()
            .map_err(|e| transfer_error(&self.label, "receive a policy", e))?
        {
            let version = sample.user_header().version;
            if newest.as_ref().is_none_or(|n| version > n.user_header().version) {
                newest = Some(sample);
            }
        }
        Ok(newest
            .filter(|s| have.is_none_or(|have| s.user_header().version > have))
            .map(|s| PolicyUpdate {
                version: s.user_header().version,
                exploration_sigma: s.user_header().exploration_sigma,
                weights: s.payload().to_vec(),
            }))
    }
}

#[cfg(test)]
mod tests {
    use std::io::{BufRead, BufReader};
    use std::process::{Command, Stdio};
    use std::sync::atomic::AtomicUsize;

    use super::*;
    use crate::validate::{RefusalKind, Spaces, Validator};

    static TESTS: AtomicUsize = AtomicUsize::new(0);

    /// A private root directory and service prefix, removed again on drop.
    struct Scratch {
        cfg: ShmConfig,
    }

    impl Scratch {
        fn new(queue_depth: usize) -> Self {
            let n = TESTS.fetch_add(1, Ordering::Relaxed);
            let pid = std::process::id();
            let root = std::env::temp_dir().join(format!("adp-shm-test-{pid}-{n}"));
            Self {
                cfg: ShmConfig {
                    service_prefix: format!("adp-test/{pid}/{n}"),
                    queue_depth,
                    root: Some(root),
                    ..ShmConfig::default()
                },
            }
        }
    }

    impl Scratch {
        /// Every node and service file under the root is gone (directories may stay).
        fn assert_no_files_left(&self) {
            fn files(dir: &std::path::Path, out: &mut Vec<PathBuf>) {
                for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
                    let path = entry.path();
                    if path.is_dir() {
                        files(&path, out);
                    } else {
                        out.push(path);
                    }
                }
            }
            let mut left = Vec::new();
            files(self.cfg.root.as_ref().unwrap(), &mut left);
            assert!(left.is_empty(), "left behind: {left:?}");
        }
    }

    impl Drop for Scratch {
        fn drop(&mut self) {
            if let Some(root) = &self.cfg.root {
                let _ = std::fs::remove_dir_all(root);
            }
        }
    }

    use testkit::watchdog;

    fn value(actor: usize, k: usize, i: usize) -> f32 {
        ((actor * 131 + k * 17 + i * 7) % 2003) as f32 * 1e-3 - 1.0
    }

    /// Record `k` of `actor`: episodes of 100 steps, the last one truncated with a final
    /// observation; lengths vary with `k`.
    fn record(actor: usize, k: usize, obs: &mut Vec<f32>, fin: &mut Vec<f32>) -> (u64, u32, bool) {
        let (episode, step) = ((k / 100) as u64, (k % 100) as u32);
        let truncated = step == 99;
        obs.clear();
        obs.extend((0..5 + k % 7).map(|i| value(actor, k, i)));
        fin.clear();
        if truncated {
            fin.extend((0..obs.len()).map(|i| value(actor, k + 1, i)));
        }
        (episode, step, truncated)
    }

    const ACT: [f32; 2] = [0.25, -0.75];

    #[test]
    fn many_actors_every_record_exactly_once_in_order_under_back_pressure() {
        const ACTORS: usize = 16;
        const EACH: usize = 2000;
        let _w = watchdog(120, "16 x 2000 records");
        let scratch = Scratch::new(8);
        let mut source = ShmStepSource::open(&scratch.cfg).unwrap();
        let senders: Vec<_> = (0..ACTORS)
            .map(|actor| {
                let cfg = scratch.cfg.clone();
                thread::spawn(move || {
                    let mut sink = ShmStepSink::open(&cfg, &format!("actor-{actor}")).unwrap();
                    let header = LeaseHeader {
                        incarnation: 7,
                        actor_id: actor as u64,
                        lease_id: 1000 + actor as u64,
                        secret: [0; 16],
                    };
                    let (mut obs, mut fin) = (Vec::new(), Vec::new());
                    for k in 0..EACH {
                        let (episode_id, step_index, truncated) = record(actor, k, &mut obs, &mut fin);
                        let step = StepView {
                            episode_id,
                            step_index,
                            policy_version: k as u64,
                            obs: &obs,
                            action: &ACT,
                            reward: k as f32,
                            terminal: false,
                            truncated,
                            final_obs: &fin,
                        };
                        sink.send(&header, &step).unwrap();
                    }
                    sink.flush().unwrap();
                })
            })
            .collect();

        let mut next = [0usize; ACTORS];
        let (mut obs, mut fin) = (Vec::new(), Vec::new());
        let (mut received, mut checked_floats) = (0, 0usize);
        while received < ACTORS * EACH {
            let n = source
                .drain(64, |lease, step| {
                    let actor = lease.actor_id as usize;
                    assert!(actor < ACTORS, "unknown actor {actor}");
                    assert_eq!((lease.incarnation, lease.lease_id), (7, 1000 + lease.actor_id));
                    let k = next[actor];
                    assert!(k < EACH, "actor {actor} delivered more than {EACH} records");
                    let (episode_id, step_index, truncated) = record(actor, k, &mut obs, &mut fin);
                    assert_eq!(
                        (step.episode_id, step.step_index, step.policy_version),
                        (episode_id, step_index, k as u64),
                        "actor {actor}: record out of order or duplicated"
                    );
                    assert_eq!(
                        (step.terminal, step.truncated, step.reward),
                        (false, truncated, k as f32)
                    );
                    assert_eq!(step.obs, &obs[..], "actor {actor} record {k}: obs");
                    assert_eq!(step.action, &ACT[..]);
                    assert_eq!(step.final_obs, &fin[..], "actor {actor} record {k}: final_obs");
                    checked_floats += step.obs.len() + step.action.len() + step.final_obs.len();
                    next[actor] += 1;
                })
                .unwrap();
            received += n;
            if n == 0 {
                thread::yield_now();
            }
        }
        for s in senders {
            s.join().unwrap();
        }
        assert_eq!(
            source.drain(usize::MAX, |_, _| panic!("extra record")).unwrap(),
            0
        );
        assert_eq!(next, [EACH; ACTORS]);
        let per_actor: usize = (0..EACH)
            .map(|k| (5 + k % 7) * (1 + usize::from(k % 100 == 99)) + ACT.len())
            .sum();
        assert_eq!(checked_floats, ACTORS * per_actor);
    }

    /// A data segment larger than the room left on /dev/shm is refused with the service, the
    /// need and the room named, before anything is created (tmpfs would hand the writer a
    /// SIGBUS later).
    #[test]
    fn a_segment_larger_than_the_room_left_is_refused_before_creation() {
        let free = free_bytes(SEGMENT_DIR).expect("/dev/shm can be inspected");
        let err = ensure_room(free + (64 << 20), "adp/t/steps")
            .unwrap_err()
            .to_string();
        for needle in ["adp/t/steps", "reserve room in /dev/shm", "MiB free"] {
            assert!(err.contains(needle), "`{needle}` not in: {err}");
        }
        assert!(ensure_room(0, "adp/t/steps").is_ok());
    }

    /// Fault injection: an iceoryx2 root that is not a usable directory (here a regular file)
    /// makes every opening fail with an error naming what and why, on the learner's side and the
    /// actor's, instead of panicking or hanging; the learner then offers gRPC only.
    #[test]
    fn an_unusable_root_path_fails_every_opening_with_a_reason() {
        let _w = watchdog(60, "unusable root");
        let mut scratch = Scratch::new(8);
        let file = std::env::temp_dir().join(format!("adp-shm-root-file-{}", std::process::id()));
        std::fs::write(&file, "not a directory").unwrap();
        scratch.cfg.root = Some(file.clone());
        let Err(learner) = ShmStepSource::open(&scratch.cfg) else {
            panic!("a file as the root");
        };
        let Err(publisher) = ShmPolicyPublisher::open(&scratch.cfg) else {
            panic!("a file as the root");
        };
        let Err(actor) = ShmStepSink::open(&scratch.cfg, "actor-0") else {
            panic!("a file as the root");
        };
        for e in [learner.to_string(), publisher.to_string(), actor.to_string()] {
            assert!(e.contains("cannot"), "{e}");
        }
        std::fs::remove_file(&file).unwrap();
    }

    /// Fault injection: more actors than the port limit. The actor beyond it is refused when it
    /// opens its publisher (so it can use gRPC), and the actors within it lose nothing.
    #[test]
    fn an_actor_beyond_the_port_limit_is_refused_and_the_others_deliver() {
        let _w = watchdog(60, "port limit");
        let mut scratch = Scratch::new(8);
        scratch.cfg.max_actors = 2;
        let mut source = ShmStepSource::open(&scratch.cfg).unwrap();
        let mut sinks: Vec<ShmStepSink> = (0..2)
            .map(|a| ShmStepSink::open(&scratch.cfg, &format!("actor-{a}")).unwrap())
            .collect();
        let Err(third) = ShmStepSink::open(&scratch.cfg, "actor-2") else {
            panic!("over the limit");
        };
        assert!(third.to_string().contains("publisher"), "{third}");
        let (mut obs, mut fin) = (Vec::new(), Vec::new());
        for (actor, sink) in sinks.iter_mut().enumerate() {
            let (episode_id, step_index, truncated) = record(actor, 0, &mut obs, &mut fin);
            let header = LeaseHeader {
                incarnation: 1,
                actor_id: actor as u64,
                lease_id: 10 + actor as u64,
                secret: [0; 16],
            };
            let step = StepView {
                episode_id,
                step_index,
                policy_version: 0,
                obs: &obs,
                action: &ACT,
                reward: 0.0,
                terminal: false,
                truncated,
                final_obs: &fin,
            };
            sink.send(&header, &step).unwrap();
            sink.flush().unwrap();
        }
        let mut from = Vec::new();
        while from.len() < 2 {
            source.drain(8, |lease, _| from.push(lease.actor_id)).unwrap();
            thread::yield_now();
        }
        from.sort_unstable();
        assert_eq!(from, [0, 1]);
    }

    #[test]
    fn truncated_records_carry_final_obs_and_oversize_records_are_refused() {
        let _w = watchdog(60, "truncated / oversize");
        let scratch = Scratch::new(8);
        let mut source = ShmStepSource::open(&scratch.cfg).unwrap();
        let mut sink = ShmStepSink::open(&scratch.cfg, "actor").unwrap();
        let header = LeaseHeader {
            incarnation: 3,
            actor_id: 4,
            lease_id: 5,
            secret: [0; 16],
        };
        let obs: Vec<f32> = (0..746).map(|i| i as f32 / 746.0).collect();
        let fin: Vec<f32> = obs.iter().map(|v| -v).collect();
        let act = [0.5f32; 20];
        let step = StepView {
            episode_id: 9,
            step_index: 199,
            policy_version: 2,
            obs: &obs,
            action: &act,
            reward: -100.0,
            terminal: false,
            truncated: true,
            final_obs: &fin,
        };
        sink.send(&header, &step).unwrap();
        let terminal = StepView {
            terminal: true,
            truncated: false,
            final_obs: &[],
            ..step
        };
        sink.send(&header, &terminal).unwrap();
        let too_big = vec![0.0f32; MAX_STEP_FLOATS];
        let e = sink
            .send(
                &header,
                &StepView {
                    obs: &too_big,
                    ..terminal
                },
            )
            .unwrap_err();
        assert!(matches!(e, PlaneError::TooLarge { plane: "shm", .. }), "{e}");
        assert!(e.to_string().contains("1556 floats, at most 1536"), "{e}");
        sink.flush().unwrap();

        let mut got = Vec::new();
        while got.len() < 2 {
            source
                .drain(8, |lease, s| {
                    assert_eq!(*lease, header);
                    got.push((
                        s.terminal,
                        s.truncated,
                        s.obs.to_vec(),
                        s.action.to_vec(),
                        s.final_obs.to_vec(),
                    ));
                })
                .unwrap();
        }
        assert_eq!(got[0], (false, true, obs.clone(), act.to_vec(), fin));
        assert_eq!(got[1], (true, false, obs, act.to_vec(), Vec::new()));
        drop((sink, source));
        scratch.assert_no_files_left();
    }

    #[test]
    fn a_slot_with_impossible_lengths_reads_as_empty_and_is_refused() {
        let mut slot = Box::new(StepSlot {
            head: SlotHead {
                incarnation: 1,
                actor_id: 2,
                lease_id: 3,
                secret: [7; 16],
                episode_id: 4,
                policy_version: 5,
                step_index: 6,
                reward: 0.0,
                flags: 0xffff_fff0,
                obs_len: 730,
                act_len: 4,
                final_len: u32::MAX,
            },
            data: [0.25; MAX_STEP_FLOATS],
        });
        let (lease, step) = read_slot(&slot);
        assert_eq!(
            (
                lease.actor_id,
                lease.secret,
                step.step_index,
                step.terminal,
                step.truncated
            ),
            (2, [7; 16], 6, false, false)
        );
        assert!(step.obs.is_empty() && step.action.is_empty() && step.final_obs.is_empty());
        let validator = Validator {
            run_id: "r".into(),
            incarnation: 1,
            spaces: Spaces {
                obs_dim: 730,
                act_dim: 4,
                laser_dim: 720,
            },
        };
        assert_eq!(
            validator.check_step(&step).unwrap_err().kind(),
            RefusalKind::Shape
        );
        slot.head.final_len = 0;
        let (_, step) = read_slot(&slot);
        assert_eq!((step.obs.len(), step.action.len()), (730, 4));
        validator.check_step(&step).unwrap();
    }

    #[test]
    fn policy_latest_wins_and_late_subscribers_get_it() {
        let _w = watchdog(60, "policy");
        let scratch = Scratch::new(8);
        let mut publisher = ShmPolicyPublisher::open(&scratch.cfg).unwrap();
        let mut early = ShmPolicySource::open(&scratch.cfg, "actor-early").unwrap();
        assert_eq!(early.poll(None).unwrap(), None);
        for v in 1..=3u64 {
            publisher
                .publish(v, 0.1 * v as f64, &vec![v as f32; 1000 + v as usize])
                .unwrap();
        }
        let got = early.poll(None).unwrap().expect("v3");
        assert_eq!((got.version, got.exploration_sigma), (3, 0.1 * 3.0));
        assert_eq!(got.weights, vec![3.0; 1003]);
        assert_eq!(early.poll(None).unwrap(), None, "nothing new");

        let mut late = ShmPolicySource::open(&scratch.cfg, "actor-late").unwrap();
        let got = loop {
            if let Some(p) = late.poll(None).unwrap() {
                break p;
            }
            thread::sleep(Duration::from_millis(2));
        };
        assert_eq!(got.version, 3);
        assert_eq!(got.weights, vec![3.0; 1003]);

        publisher.publish(4, 0.05, &[4.0; 10]).unwrap();
        assert_eq!(late.poll(Some(4)).unwrap(), None, "not newer than what we have");
        publisher.publish(5, 0.05, &[5.0; 10]).unwrap();
        assert_eq!(early.poll(Some(5)).unwrap(), None);
        publisher.publish(6, 0.05, &[6.0; 10]).unwrap();
        assert_eq!(early.poll(Some(3)).unwrap().map(|p| p.version), Some(6));

        let e = publisher.publish(7, 0.0, &vec![0.0; (1 << 20) + 1]).unwrap_err();
        assert!(matches!(e, ShmError::TooLarge { .. }), "{e}");
        // Many more versions than the segment has chunks: old ones are recycled.
        for v in 8..40u64 {
            publisher.publish(v, 0.0, &[v as f32; 100]).unwrap();
        }
        assert_eq!(early.poll(Some(3)).unwrap().map(|p| p.version), Some(39));
        drop((publisher, early, late));
        scratch.assert_no_files_left();
    }

    #[test]
    fn learner_ends_can_move_to_other_threads() {
        fn send<T: Send>() {}
        send::<ShmStepSource>();
        send::<ShmPolicyPublisher>();
    }

    #[test]
    fn dead_nodes_are_looked_for_at_most_once_per_period_per_root() {
        let t0 = Instant::now();
        let (a, b) = (b"/scan-gate-test/a".as_slice(), b"/scan-gate-test/b".as_slice());
        assert!(scan_due(a, t0), "the first look under a root is due");
        assert!(
            !scan_due(a, t0 + DEAD_NODE_SCAN_PERIOD / 2),
            "a second look within the period is skipped"
        );
        assert!(
            scan_due(b, t0 + DEAD_NODE_SCAN_PERIOD / 2),
            "another root has its own period"
        );
        assert!(
            scan_due(a, t0 + DEAD_NODE_SCAN_PERIOD),
            "a look is due again after the period"
        );
        assert!(!scan_due(a, t0 + DEAD_NODE_SCAN_PERIOD), "and then skipped again");
    }

    #[test]
    fn sink_without_learner_reports_disconnected() {
        let _w = watchdog(60, "no learner");
        let scratch = Scratch::new(4);
        let mut sink = ShmStepSink::open(&scratch.cfg, "actor").unwrap();
        let header = LeaseHeader {
            incarnation: 1,
            actor_id: 1,
            lease_id: 1,
            secret: [0; 16],
        };
        let step = StepView {
            episode_id: 0,
            step_index: 0,
            policy_version: 0,
            obs: &[0.0; 8],
            action: &[0.0; 2],
            reward: 0.0,
            terminal: false,
            truncated: false,
            final_obs: &[],
        };
        let e = sink.flush().unwrap_err();
        assert!(matches!(e, PlaneError::Disconnected { plane: "shm", .. }), "{e}");
        assert!(e.to_string().contains("/steps"), "{e}");
        let e = sink.send(&header, &step).unwrap_err();
        assert!(matches!(e, PlaneError::Disconnected { .. }), "{e}");

        // A learner that leaves after taking some records.
        let mut source = ShmStepSource::open(&scratch.cfg).unwrap();
        sink.send(&header, &step).unwrap();
        sink.flush().unwrap();
        assert_eq!(source.drain(10, |_, _| {}).unwrap(), 1);
        drop(source);
        assert!(matches!(sink.flush(), Err(PlaneError::Disconnected { .. })));
        assert!(matches!(
            sink.send(&header, &step),
            Err(PlaneError::Disconnected { .. })
        ));
    }

    const CHILD_ROOT: &str = "ADP_SHM_TEST_CHILD_ROOT";
    const CHILD_PREFIX: &str = "ADP_SHM_TEST_CHILD_PREFIX";
    const CHILD_READY: &str = "adp-shm-child-ready";

    /// Helper process of the killed-learner tests: subscribes as the learner (queue of 4),
    /// never drains, and waits to be killed (gives up after a minute).
    #[test]
    #[ignore = "helper process started by the killed-learner tests"]
    fn child_learner_process() {
        let (Ok(root), Ok(prefix)) = (std::env::var(CHILD_ROOT), std::env::var(CHILD_PREFIX)) else {
            return;
        };
        let cfg = ShmConfig {
            service_prefix: prefix,
            queue_depth: 4,
            root: Some(root.into()),
            ..ShmConfig::default()
        };
        let _source = ShmStepSource::open(&cfg).unwrap();
        println!("{CHILD_READY}");
        thread::sleep(Duration::from_secs(60));
    }

    /// A learner process is killed (SIGKILL) while an actor is blocked on its full queue: the
    /// actor's send ends with `Disconnected` instead of blocking forever. With `sink_first`
    /// the learner attached to the actor's connection (the blocked send waits in iceoryx2's
    /// back-pressure loop); otherwise it never did (the sink's re-send loop waits).
    fn killed_learner(sink_first: bool) {
        let _w = watchdog(60, "killed learner");
        let scratch = Scratch::new(4);
        let mut sink = sink_first.then(|| ShmStepSink::open(&scratch.cfg, "actor").unwrap());
        let mut child = Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "shm::tests::child_learner_process",
                "--ignored",
                "--nocapture",
            ])
            .env(CHILD_ROOT, scratch.cfg.root.as_ref().unwrap())
            .env(CHILD_PREFIX, &scratch.cfg.service_prefix)
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
        assert!(
            lines.any(|l| l.unwrap().trim() == CHILD_READY),
            "child did not start"
        );
        let mut sink = sink
            .take()
            .unwrap_or_else(|| ShmStepSink::open(&scratch.cfg, "actor").unwrap());
        // `attempts` counts send calls begun, `sent` the ones that returned.
        let attempts = Arc::new(AtomicUsize::new(0));
        let sent = Arc::new(AtomicUsize::new(0));
        let (tried, counter) = (Arc::clone(&attempts), Arc::clone(&sent));
        let sender = thread::spawn(move || {
            let header = LeaseHeader {
                incarnation: 1,
                actor_id: 1,
                lease_id: 1,
                secret: [0; 16],
            };
            loop {
                let step = StepView {
                    episode_id: 0,
                    step_index: counter.load(Ordering::Relaxed) as u32,
                    policy_version: 0,
                    obs: &[0.0; 8],
                    action: &[0.0; 2],
                    reward: 0.0,
                    terminal: false,
                    truncated: false,
                    final_obs: &[],
                };
                tried.fetch_add(1, Ordering::SeqCst);
                if let Err(e) = sink.send(&header, &step) {
                    return e;
                }
                counter.fetch_add(1, Ordering::SeqCst);
            }
        });
        // The child never reads: the fifth send is the one that waits on a full queue. Kill
        // the learner once it has begun (no fixed sleep: the watchdog bounds the wait).
        while attempts.load(Ordering::SeqCst) < 5 {
            thread::sleep(Duration::from_millis(1));
        }
        child.kill().unwrap();
        child.wait().unwrap();
        let e = sender.join().unwrap();
        assert!(matches!(e, PlaneError::Disconnected { plane: "shm", .. }), "{e}");
        assert_eq!(
            sent.load(Ordering::SeqCst),
            4,
            "the queue held 4 and the fifth send never went through"
        );
    }

    #[test]
    fn blocked_sink_notices_a_killed_learner() {
        killed_learner(true);
    }

    #[test]
    fn unattached_sink_notices_a_killed_learner() {
        killed_learner(false);
    }
}
