//! Settings of the learner process (the `[service]` table of a run config).

use std::path::PathBuf;

use proto::auth::TlsFiles;
use serde::{Deserialize, Serialize};
use settings::{ActionMap, ActionSpace, EnvConfig, PlannerKind};

use crate::error::SettingsError;
use learner::config::Td3Config;
use learner::LearnerDevice;

/// How the learner process serves actors. Every field has a default; unknown keys are refused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ServiceConfig {
    /// Address the gRPC server (control plane, and the data plane across nodes) binds.
    /// Port 0 picks a free port; the bound address is written to `learner.addr` in the run
    /// directory.
    pub listen: String,
    /// Offer the iceoryx2 shared-memory data plane to actors on this host (they still use gRPC
    /// for the control plane). Actors on other hosts always stream steps over gRPC. On by
    /// default.
    pub shared_memory: bool,
    /// Most actors on the shared-memory plane at once (iceoryx2 fixes its ports when the
    /// learner creates the services). An actor beyond it that runs `--data-plane auto` streams
    /// over gRPC instead; one that insists on `shm` fails with the reason. Default 256.
    pub shm_max_actors: u32,
    /// How often actors send a heartbeat (ms).
    pub heartbeat_ms: u32,
    /// A lease expires this long (ms) after the last heartbeat; its world is dealt again and
    /// its late data refused.
    pub lease_ttl_ms: u32,
    /// A lease whose episodes make no progress (no step stored, no report accepted) for this
    /// long (ms) is dropped even though its actor keeps heartbeating (a hung main loop with a
    /// live heartbeat thread, a policy version that never arrives); its world is dealt again.
    /// 0 (the default) means 4 x `lease_ttl_ms`. The clock stands still while the learner
    /// itself holds actors up (rate limiter, an unpublished policy). A lease with a refused
    /// step is dropped at once: its episode can never complete.
    pub progress_timeout_ms: u32,
    /// A cycle does not wait forever for its slowest lease: once a lease finished, a cycle
    /// ends at the latest one span after its first assignment, the span being this multiple
    /// of the median episode time of the newest 64 finished leases times
    /// `episodes_per_assignment` (at least `cycle_deadline_floor_ms`). Leases still open then
    /// are ended (their worlds dealt again first; their steps stored so far stay stored,
    /// each counted once, their episodes abandoned: never marked terminal; later steps under
    /// them are refused); their actors are late: their next assignments are off the cycle
    /// barrier and end one span after they were assigned, until one finishes. A lease without
    /// progress for this multiple of the median episode time (at least the floor) ends too, if
    /// that is shorter than `progress_timeout_ms`. 0 turns both off (the cycle waits for every
    /// lease, bounded only by `progress_timeout_ms`). Default 4.
    pub cycle_deadline_multiple: u32,
    /// No cycle span or no-progress bound of `cycle_deadline_multiple` is shorter than this
    /// (ms). Default 10000.
    pub cycle_deadline_floor_ms: u32,
    /// Allow `listen` on an address other than loopback without `[service.tls]` (the token
    /// then travels in clear text). Off by default; `adp learner --allow-insecure-listen`.
    pub allow_insecure_listen: bool,
    /// Episodes per assignment (the ADP cycle runs two).
    pub episodes_per_assignment: u32,
    /// An idle actor asks for work again after this long (ms).
    pub idle_retry_ms: u32,
    /// Seconds between periodic checkpoints (a checkpoint is also written on SIGTERM/SIGINT
    /// and at the end of the budget).
    pub checkpoint_every_s: f64,
    /// Checkpoints kept (newest first); older ones are deleted.
    pub keep_checkpoints: usize,
    /// Include the replay buffer in checkpoints (up to ~310 MB at 200K steps), so a resumed run
    /// continues with the same data; without it a resumed run refills the buffer.
    pub checkpoint_replay: bool,
    /// Seconds between writes of `status.json` and TensorBoard service scalars.
    pub status_every_s: f64,
    /// Fit the actor to the DDP schedule (with the hand-tuned gains in the objective-weight
    /// spaces) before training (the ADP paper's initialization); skipped in the velocity space,
    /// which has no DDP.
    pub ddp_init: bool,
    /// Start from this constant action instead: one value per action dimension of the run's
    /// space, each in [-1, 1], in the space's normalized box (the coordinates of `adp eval`'s
    /// constant actions and of an experiment's constant search; under `[env] action_map =
    /// "ddp-centred"` the actor is fitted to the output that selects it). When given, it
    /// overrides `ddp_init` (which is then ignored) and applies in every space, velocity
    /// included. Absent by default, and then not written to a configuration.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub init_action: Option<Vec<f64>>,
    /// TLS for the gRPC server (`cert` and `key`; with `ca`, clients must present certificates).
    pub tls: Option<TlsFiles>,
    /// Most connections served at once by each listener: the TCP one and the Unix socket have
    /// a budget each, so that a flood of one cannot lock the other out. One more closes the
    /// listener's oldest connection that has not made a request with the run token (counted
    /// and logged); when every one has, it waits until one closes (logged). The learner also
    /// lowers it
    /// to what its open-file limit leaves after the files it needs for itself (checkpoints,
    /// status), shared by the two. Default 1024.
    pub max_connections: u32,
    /// Most TCP connections open at once from one source address; one more is closed at once
    /// (counted and logged). An `adp actor` needs one connection, so a host running more
    /// actors than this over TCP needs it raised (actors on the learner's host use the Unix
    /// socket). Default 256.
    pub max_connections_per_ip: u32,
    /// A connection that has not sent the HTTP/2 preface (or the start of its TLS handshake)
    /// within this long (ms) is closed. Default 5000.
    pub handshake_timeout_ms: u32,
    /// A connection that has made no request carrying the run token within this long (ms) of
    /// being accepted is closed, whatever else it sends (HTTP/2 settings, pings, requests
    /// without the token); one that has is never closed for it. An actor makes its first
    /// request (`Register`) at once. Default 10000.
    pub auth_deadline_ms: u32,
    /// Most `WatchPolicy` streams open at once over all actors (more are refused with
    /// RESOURCE_EXHAUSTED). Every stream shares one encoded copy of the newest policy. Default
    /// 1024.
    pub max_policy_streams: u32,
    /// Most `WatchPolicy` streams open at once per registration (an actor needs one); one more
    /// ends the registration's oldest (counted and logged), so an actor that reconnects is
    /// never refused for its own stale stream. Default 1.
    pub policy_streams_per_actor: u32,
    /// Most `WatchPolicy` streams open at once from one TCP source address; more are refused
    /// with RESOURCE_EXHAUSTED (counted and logged), so one host cannot take every slot of
    /// `max_policy_streams`. Like `max_connections_per_ip`, raise it for a host that runs more
    /// actors than this over TCP. Default 256.
    pub policy_streams_per_ip: u32,
    /// Most live registrations (actors heartbeating within the lease TTL) made from one TCP
    /// source address; one more `Register` is refused with RESOURCE_EXHAUSTED (counted and
    /// logged), so one host cannot fill the registry. A registration that proves to replace
    /// one of the address's (`previous_actor_id` with its secret) does not count twice. Like
    /// `max_connections_per_ip`, raise it for a host that runs more actors than this over TCP.
    /// Default 256.
    pub registrations_per_ip: u32,
    /// A policy version still being sent on a `WatchPolicy` stream is kept this long (ms) after
    /// a newer one is published (at most two superseded versions are kept); a stream that has
    /// not sent it by then ends (the actor opens a new one and gets the newest). Streams send
    /// copies of 16 KiB pieces, so a reader that never reads holds a piece, not a version.
    /// Default 10000.
    pub policy_send_grace_ms: u32,
    /// Most bytes held at once in request messages that have begun to arrive but are not
    /// complete, over all connections; one more ends the oldest such message (its request
    /// fails with RESOURCE_EXHAUSTED). Default 67108864 (64 MiB).
    pub max_incomplete_bytes: u64,
    /// The same for one connection (at least one largest request, 1 MiB). Default 4194304
    /// (4 MiB).
    pub max_incomplete_bytes_per_connection: u64,
    /// A request message not complete within this long (ms) of its first byte fails its
    /// request with DEADLINE_EXCEEDED. Default 10000.
    pub message_deadline_ms: u32,
    /// Ranks whose actor has been dead (no heartbeat, no lease) for this long (ms) are
    /// forgotten: their records leave `status.json` and checkpoints, their counters are
    /// added to the aggregate of pruned ranks. Default 600000 (10 minutes).
    pub rank_forget_ms: u64,
    /// Most ranks whose actor is dead kept in `status.json` and checkpoints (the most
    /// recently seen); older dead ones are forgotten before `rank_forget_ms`. Default 256.
    pub dead_ranks_kept: u32,
}

impl ServiceConfig {
    /// The registry's deadline rule (`cycle_deadline_multiple`, `cycle_deadline_floor_ms`).
    pub fn deadline_rule(&self) -> scheduler::DeadlineRule {
        scheduler::DeadlineRule {
            multiple: self.cycle_deadline_multiple,
            floor_ms: u64::from(self.cycle_deadline_floor_ms),
        }
    }

    /// The no-progress bound of a lease in ms (`progress_timeout_ms`, or 4 x `lease_ttl_ms`).
    pub fn progress_timeout(&self) -> u64 {
        match self.progress_timeout_ms {
            0 => 4 * u64::from(self.lease_ttl_ms),
            ms => u64::from(ms),
        }
    }

    /// What a fresh run's actor is fitted to before training: `init_action` when given, else
    /// with `ddp_init` the output that selects DDP under `map`, else nothing. The learner and
    /// an experiment's untrained control both start from it.
    pub fn start_action(&self, map: ActionMap, space: ActionSpace) -> StartAction {
        let ddp = space.ddp_action();
        match &self.init_action {
            Some(a) => StartAction::Given(
                a.iter()
                    .zip(&ddp)
                    .map(|(&x, &d)| map.to_policy(x, d) as f32)
                    .collect(),
            ),
            None if self.ddp_init => {
                StartAction::Ddp(map.ddp_policy_action(space).iter().map(|&a| a as f32).collect())
            }
            None => StartAction::Random,
        }
    }

    /// Refuses an `init_action` that does not fit `space`: another number of values than the
    /// space's dimensions, or a value outside [-1, 1] (naming its index and value).
    pub fn check_init_action(&self, space: ActionSpace) -> Result<(), SettingsError> {
        let Some(a) = &self.init_action else {
            return Ok(());
        };
        if a.len() != space.dim() {
            return Err(SettingsError::InitActionLength {
                len: a.len(),
                space: space.to_string(),
                dim: space.dim(),
            });
        }
        match a
            .iter()
            .position(|v| !(v.is_finite() && (-1.0..=1.0).contains(v)))
        {
            Some(index) => Err(SettingsError::InitActionValue {
                index,
                value: a[index],
            }),
            None => Ok(()),
        }
    }

    /// Refuses settings that cannot work: a heartbeat not shorter than the lease, no port for
    /// shared memory, a connection limit or deadline of 0, and a network address other than
    /// loopback without TLS unless `allow_insecure_listen`.
    pub fn check(&self) -> Result<(), SettingsError> {
        if self.shared_memory && self.shm_max_actors == 0 {
            return Err(SettingsError::ShmMaxActors);
        }
        if self.heartbeat_ms == 0 || self.lease_ttl_ms <= self.heartbeat_ms {
            return Err(SettingsError::LeaseTtl {
                lease_ttl_ms: self.lease_ttl_ms,
                heartbeat_ms: self.heartbeat_ms,
            });
        }
        if self.progress_timeout_ms != 0 && self.progress_timeout_ms <= self.heartbeat_ms {
            return Err(SettingsError::ProgressTimeout {
                progress_timeout_ms: self.progress_timeout_ms,
                heartbeat_ms: self.heartbeat_ms,
            });
        }
        for (key, value) in [
            ("max_connections", self.max_connections),
            ("max_connections_per_ip", self.max_connections_per_ip),
            ("handshake_timeout_ms", self.handshake_timeout_ms),
            ("auth_deadline_ms", self.auth_deadline_ms),
            ("policy_streams_per_ip", self.policy_streams_per_ip),
            ("policy_send_grace_ms", self.policy_send_grace_ms),
            ("registrations_per_ip", self.registrations_per_ip),
            ("message_deadline_ms", self.message_deadline_ms),
        ] {
            if value == 0 {
                return Err(SettingsError::ZeroConnectionLimit { key });
            }
        }
        let least = proto::grpc::MAX_REQUEST_BYTES as u64 + 5;
        if self.max_incomplete_bytes_per_connection < least
            || self.max_incomplete_bytes < self.max_incomplete_bytes_per_connection
        {
            return Err(SettingsError::IncompleteBytes {
                per_connection: self.max_incomplete_bytes_per_connection,
                total: self.max_incomplete_bytes,
                least,
            });
        }
        if self.tls.is_none() && !self.allow_insecure_listen && !is_loopback_listen(&self.listen) {
            return Err(SettingsError::InsecureListen {
                listen: self.listen.clone(),
            });
        }
        Ok(())
    }
}

/// Whether `listen` (`host:port`) names a loopback address (`127.0.0.0/8`, `::1`,
/// `localhost`).
pub fn is_loopback_listen(listen: &str) -> bool {
    if let Ok(addr) = listen.parse::<std::net::SocketAddr>() {
        return addr.ip().is_loopback();
    }
    let host = listen.rsplit_once(':').map_or(listen, |(h, _)| h);
    let host = host.trim_start_matches('[').trim_end_matches(']');
    host.eq_ignore_ascii_case("localhost")
        || host.parse::<std::net::IpAddr>().is_ok_and(|ip| ip.is_loopback())
}

impl Default for ServiceConfig {
    fn default() -> Self {
        Self {
            listen: "127.0.0.1:0".into(),
            shared_memory: true,
            shm_max_actors: 256,
            heartbeat_ms: 1000,
            lease_ttl_ms: 15_000,
            progress_timeout_ms: 0,
            cycle_deadline_multiple: 4,
            cycle_deadline_floor_ms: 10_000,
            allow_insecure_listen: false,
            episodes_per_assignment: 2,
            idle_retry_ms: 100,
            checkpoint_every_s: 600.0,
            keep_checkpoints: 3,
            checkpoint_replay: true,
            status_every_s: 1.0,
            ddp_init: true,
            init_action: None,
            tls: None,
            max_connections: 1024,
            max_connections_per_ip: 256,
            handshake_timeout_ms: 5000,
            auth_deadline_ms: 10_000,
            max_policy_streams: 1024,
            policy_streams_per_actor: 1,
            policy_streams_per_ip: 256,
            registrations_per_ip: 256,
            policy_send_grace_ms: 10_000,
            max_incomplete_bytes: 64 << 20,
            max_incomplete_bytes_per_connection: 4 << 20,
            message_deadline_ms: 10_000,
            rank_forget_ms: 600_000,
            dead_ranks_kept: 256,
        }
    }
}

/// What a fresh run's actor starts from ([`ServiceConfig::start_action`]): the policy output
/// it is fitted to, if any.
#[derive(Debug, Clone, PartialEq)]
pub enum StartAction {
    /// `[service] init_action`, as policy outputs.
    Given(Vec<f32>),
    /// The output that selects DDP (`ddp_init`). The learner skips it in the velocity space,
    /// which has no DDP.
    Ddp(Vec<f32>),
    /// No fit: the actor's random initialization.
    Random,
}

/// Everything a learner process needs to start one run.
#[derive(Debug, Clone)]
pub struct LearnerOptions {
    /// The run directory (`runs/<name>`): checkpoints, TensorBoard, status, address file.
    pub run_dir: PathBuf,
    /// The run id used when the run starts fresh (a resumed run keeps its own).
    pub run_id: String,
    /// TD3 hyper-parameters (their `obs_dim`/`act_dim` must fit `space`).
    pub td3: Td3Config,
    /// Where the learner computes (a checkpoint resumes on either device).
    pub device: LearnerDevice,
    /// Service settings.
    pub service: ServiceConfig,
    /// The planner actors run (`dwa`, `mppi`, `log-mppi`, `system`).
    pub planner: PlannerKind,
    /// The planner's speed cap (m/s).
    pub max_speed: f64,
    /// The ADP action space.
    pub space: ActionSpace,
    /// The actors' environment settings (sent to actors as the run spec's `EnvConfig`).
    pub env: EnvConfig,
    /// The training worlds: a list of world ids (embedded or generated, see
    /// `sim::catalog::load`), or a fresh generated world for every assignment.
    pub worlds: scheduler::WorldPool,
    /// Total agent steps of the run; the learner stops assigning work once they are stored.
    /// Assignments already dealt still run their episodes to the end and are trained on (a
    /// partial episode would be wasted), so a run stores up to one assignment per actor more;
    /// then the learner finishes the updates they call for.
    pub budget_steps: u64,
    /// The run's secret token (every gRPC call must carry it).
    pub token: String,
    /// Continue from the newest valid checkpoint in `run_dir/checkpoints` (an error if none).
    pub resume: bool,
    /// Stop the process gracefully (final checkpoint) on SIGINT/SIGTERM.
    pub handle_signals: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `init_action` is checked per index against the space, overrides `ddp_init`, and maps
    /// to policy outputs through the action map; without it `ddp_init` decides.
    #[test]
    fn init_action_is_checked_per_index_and_overrides_ddp_init() {
        let space = ActionSpace::Decremental;
        let with = |a: Vec<f64>| ServiceConfig {
            init_action: Some(a),
            ..ServiceConfig::default()
        };
        with(vec![0.5, -0.25, 1.0, -1.0])
            .check_init_action(space)
            .unwrap();
        let e = with(vec![0.5, 1.5, 0.0, 0.0])
            .check_init_action(space)
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            "[service] init_action[1] = 1.5 is outside [-1, 1] (normalized actions)"
        );
        let e = with(vec![0.0, 0.0, f64::NAN, 0.0])
            .check_init_action(space)
            .unwrap_err();
        assert!(e.to_string().starts_with("[service] init_action[2] = NaN"), "{e}");
        let e = with(vec![0.0; 3]).check_init_action(space).unwrap_err();
        assert_eq!(
            e.to_string(),
            "[service] init_action has 3 values, but the decremental action space has 4 dimensions"
        );
        ServiceConfig::default().check_init_action(space).unwrap();

        let given = with(vec![0.5, -0.25, 1.0, -1.0]);
        assert_eq!(
            given.start_action(ActionMap::Affine, space),
            StartAction::Given(vec![0.5, -0.25, 1.0, -1.0])
        );
        // ddp_init off or on, the given action wins.
        let off = ServiceConfig {
            ddp_init: false,
            ..given.clone()
        };
        assert_eq!(
            off.start_action(ActionMap::Affine, space),
            given.start_action(ActionMap::Affine, space)
        );
        // The DDP action itself maps to 0 under the DDP-centred map.
        let ddp = with(space.ddp_action());
        assert_eq!(
            ddp.start_action(ActionMap::DdpCentred, space),
            StartAction::Given(vec![0.0; 4])
        );
        let ddp_f32: Vec<f32> = space.ddp_action().iter().map(|&a| a as f32).collect();
        assert_eq!(
            ServiceConfig::default().start_action(ActionMap::Affine, space),
            StartAction::Ddp(ddp_f32)
        );
        let random = ServiceConfig {
            ddp_init: false,
            ..ServiceConfig::default()
        };
        assert_eq!(random.start_action(ActionMap::Affine, space), StartAction::Random);
        // Absent, it is not written; given, it reads back.
        let text = serde_json::to_string(&ServiceConfig::default()).unwrap();
        assert!(!text.contains("init_action"), "{text}");
        let back: ServiceConfig = serde_json::from_str(&serde_json::to_string(&given).unwrap()).unwrap();
        assert_eq!(back, given);
    }

    #[test]
    fn non_loopback_listen_without_tls_is_refused_naming_the_flag() {
        let mut c = ServiceConfig::default();
        c.check().unwrap();
        for listen in ["127.0.0.1:0", "[::1]:5000", "localhost:7000", "127.0.0.2:1"] {
            c.listen = listen.into();
            c.check().unwrap_or_else(|e| panic!("{listen}: {e}"));
        }
        for listen in ["0.0.0.0:0", "10.1.2.3:50051", "[::]:0", "node17:50051"] {
            c.listen = listen.into();
            let e = c.check().unwrap_err().to_string();
            assert!(e.contains("--allow-insecure-listen") && !e.contains('\n'), "{e}");
        }
        c.allow_insecure_listen = true;
        c.check().unwrap();
    }

    #[test]
    fn progress_timeout_defaults_to_four_lease_ttls() {
        let mut c = ServiceConfig::default();
        assert_eq!(c.progress_timeout(), 60_000);
        c.progress_timeout_ms = 1500;
        assert_eq!(c.progress_timeout(), 1500);
        c.progress_timeout_ms = 10;
        assert!(c.check().unwrap_err().to_string().contains("progress_timeout_ms"));
    }

    #[test]
    fn connection_limits_and_deadlines_of_zero_are_refused_by_name() {
        let c = ServiceConfig {
            auth_deadline_ms: 0,
            ..ServiceConfig::default()
        };
        let e = c.check().unwrap_err().to_string();
        assert!(e.contains("auth_deadline_ms") && e.contains("at least 1"), "{e}");
        let c = ServiceConfig {
            max_connections_per_ip: 0,
            ..ServiceConfig::default()
        };
        let e = c.check().unwrap_err().to_string();
        assert!(e.contains("max_connections_per_ip"), "{e}");
    }
}
