"""The actor loop over gRPC: register, take assignments, follow policy versions, run episodes
in the user's environment, stream steps, report episodes (the Python twin of actor/src/run.rs).
"""

import os
import socket
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional

import grpc
import numpy as np

from . import checksum as ck
from ._proto import adp_pb2 as pb
from ._proto.stubs import Stub
from .action import ActionMap, ActionSpace
from .policy import MlpPolicy
from .spec import action_map_name, action_space_name, laser_layout, planner_name

MAX_MESSAGE_BYTES = 64 << 20
BATCH_RECORDS = 64
OUTCOMES = {"success": pb.OUTCOME_SUCCESS, "collision": pb.OUTCOME_COLLISION, "timeout": pb.OUTCOME_TIMEOUT}
# What this client registers as (`actor_kind`): the learner's status.json counts actors,
# episodes and steps per kind, so a mixed fleet of Rust and Python actors can be told apart.
ACTOR_KIND = "python"


class AdpError(Exception):
    """Base class of the client's errors."""


class ConfigError(AdpError):
    """A bad client setting (address, token file, certificates)."""


class LearnerUnreachable(AdpError):
    """The learner could not be reached (or kept refusing the session) for too long."""


class StepsRefused(AdpError):
    """The learner refused step records; `reason` is its first reason."""

    def __init__(self, refused: int, sent: int, reason: str):
        super().__init__(f"the learner refused {refused} of {sent} step records: {reason}")
        self.refused, self.sent, self.reason = refused, sent, reason


class EnvironmentFault(AdpError):
    """The user's environment returned something the run cannot use (wrong shape, NaN...)."""


class _Reconnect(Exception):
    """Internal: end the session and register again."""


@dataclass
class RunInfo:
    """What the learner told this actor at registration: the run and its shared settings."""

    run_id: str
    incarnation: int
    actor_id: int
    obs_dim: int
    act_dim: int
    action_space: ActionSpace
    planner: str
    max_speed: float
    run_seed: int
    policy_dims: list
    heartbeat_ms: int
    lease_ttl_ms: int
    # The run's `[env]` settings (the RunSpec's `EnvConfig` message: laser_clip_m,
    # agent_period_cycles, observe_tracks, rewards...).
    env: object
    # How the policy's output becomes a box action (the run's `[env] action_map`).
    action_map: ActionMap
    # The observation's laser layout: "scan" or "sectors:N" (the run's `[env] observation`).
    laser_layout: str

    def schedule(self, action, n: int = 20):
        """The rollout schedule a policy output selects: the action map, then the action
        space (exactly what the Rust actors' environment runs)."""
        return self.action_map.schedule(self.action_space, action, n)


def read_token_file(path) -> str:
    """Reads the run token (trimmed); refuses a file others may read, as the Rust side does."""
    try:
        mode = os.stat(path).st_mode & 0o777
        text = open(path, encoding="utf-8").read().strip()
    except OSError as e:
        raise ConfigError(f"token file {path}: {e}") from e
    if mode & 0o077:
        raise ConfigError(f"token file {path}: mode {mode:o} lets others read it (chmod 600)")
    if not text:
        raise ConfigError(f"token file {path}: it is empty")
    return text


def _read(path, what):
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError as e:
        raise ConfigError(f"{what} {path}: {e}") from e


class Connection:
    """A gRPC channel to the learner with the run token on every call.

    `address` is `host:port` or `unix:PATH`. TLS: `tls_ca` (PEM file of the CA that signed the
    learner's certificate), optionally `tls_cert`/`tls_key` for mutual TLS and `tls_domain`
    when the certificate names another host than `address`.
    """

    def __init__(self, address, token=None, token_file=None, tls_ca=None, tls_cert=None, tls_key=None, tls_domain=None):
        if token is None and token_file is not None:
            token = read_token_file(token_file)
        self.address = address
        self._metadata = (("authorization", f"Bearer {token}"),) if token else ()
        opts = [
            ("grpc.max_send_message_length", MAX_MESSAGE_BYTES),
            ("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
        ]
        if tls_ca is not None:
            if (tls_cert is None) != (tls_key is None):
                raise ConfigError("mutual TLS needs both tls_cert and tls_key")
            creds = grpc.ssl_channel_credentials(
                root_certificates=_read(tls_ca, "TLS CA"),
                private_key=_read(tls_key, "TLS key") if tls_key else None,
                certificate_chain=_read(tls_cert, "TLS certificate") if tls_cert else None,
            )
            if tls_domain:
                opts.append(("grpc.ssl_target_name_override", tls_domain))
            self.channel = grpc.secure_channel(address, creds, options=opts)
        else:
            self.channel = grpc.insecure_channel(address, options=opts)
        self.control = Stub(self.channel, "Control")
        self.data = Stub(self.channel, "Data")

    def call(self, method, request, timeout=None):
        """Calls a unary method with the token."""
        return method(request, metadata=self._metadata, timeout=timeout)

    def push(self, batch, timeout=60.0):
        """Sends one step batch (one client stream) and returns the learner's Ack."""
        return self.data.PushSteps(iter([batch]), metadata=self._metadata, timeout=timeout)

    def watch(self, request):
        """The server stream of policy snapshots newer than `request.have_version`."""
        return self.data.WatchPolicy(request, metadata=self._metadata)

    def close(self):
        """Closes the channel."""
        self.channel.close()


def exploration_seed(seed: int) -> int:
    """Mixes an episode seed into the exploration stream's seed (splitmix64 finalizer, as the
    Rust actor)."""
    m = (1 << 64) - 1
    z = seed ^ 0x9E3779B97F4A7C15
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & m
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & m
    return z ^ (z >> 31)


class Session:
    """One registration with the learner: run info, lease heartbeats, policy stream, step
    batching. Ends (`close`) when the learner restarts, forgets it, or the run is over.
    The low-level building block of `Actor`; usable on its own for custom loops.

    `previous` is the `(actor_id, secret)` of the registration this one replaces (the same
    process's earlier session): the learner retires it at once. Without it, a live
    registration of the same rank keeps its lease and the new one works beside it."""

    def __init__(self, conn: Connection, rank: int, log: Callable[[str], None], previous=None):
        self.conn, self.rank, self.log = conn, rank, log
        prev_id, prev_secret = previous if previous is not None else (0, b"")
        reply = conn.call(
            conn.control.Register,
            pb.RegisterRequest(rank=rank, host=socket.gethostname()[:255], pid=os.getpid(), run_id="",
                               actor_kind=ACTOR_KIND, previous_actor_id=prev_id,
                               previous_actor_secret=prev_secret),
            timeout=10.0,
        )
        s = reply.spec
        self.run = pb.RunRef(run_id=reply.run.run_id, incarnation=reply.run.incarnation)
        self.info = RunInfo(
            run_id=reply.run.run_id,
            incarnation=reply.run.incarnation,
            actor_id=reply.actor_id,
            obs_dim=s.obs_dim,
            act_dim=s.act_dim,
            action_space=ActionSpace(action_space_name(s.action_space)),
            planner=planner_name(s.planner),
            max_speed=s.max_speed,
            run_seed=s.run_seed,
            policy_dims=list(s.policy_dims),
            heartbeat_ms=s.heartbeat_ms,
            lease_ttl_ms=s.lease_ttl_ms,
            env=s.env,
            action_map=ActionMap(action_map_name(s.env)),
            laser_layout=laser_layout(s.env),
        )
        self.actor_id = reply.actor_id
        # This registration's credential: every request naming actor_id carries it.
        self.secret = bytes(reply.actor_secret)
        if len(self.secret) != 16:
            # A learner older than per-actor credentials (this client speaks the current contract).
            raise ConfigError(f"register: the learner sent a {len(self.secret)}-byte actor secret, not 16 "
                              "(a learner older than this client?)")
        self._lock = threading.Lock()
        self.lease = 0
        self.lease_lost = threading.Event()
        self.shutdown = threading.Event()
        self.gone = threading.Event()
        self._stop = threading.Event()
        self._policy = None  # (version, sigma, MlpPolicy)
        self._policy_cv = threading.Condition()
        self._policy_error: Optional[str] = None
        self._batch = []
        self._batch_lease = 0
        self._hb = threading.Thread(target=self._heartbeats, name="adp-heartbeat", daemon=True)
        self._hb.start()
        self._watch_call = None
        self._pw = threading.Thread(target=self._watch, name="adp-policy", daemon=True)
        self._pw.start()

    # -- background threads ---------------------------------------------------------------
    def _heartbeats(self):
        every = max(self.info.heartbeat_ms, 10) / 1000.0
        ttl = max(self.info.lease_ttl_ms, self.info.heartbeat_ms, 10) / 1000.0
        last_ok = time.monotonic()
        while not self._stop.wait(every):
            with self._lock:
                lease = self.lease
            try:
                r = self.conn.call(
                    self.conn.control.Heartbeat,
                    pb.HeartbeatRequest(run=self.run, actor_id=self.actor_id, lease_id=lease,
                                        actor_secret=self.secret),
                    timeout=max(every, 1.0),
                )
            except grpc.RpcError as e:
                if e.code() in (grpc.StatusCode.FAILED_PRECONDITION, grpc.StatusCode.NOT_FOUND):
                    self.gone.set()
                    self.lease_lost.set()
                elif time.monotonic() - last_ok > ttl:
                    self.gone.set()
                    self.lease_lost.set()
                continue
            last_ok = time.monotonic()
            if not r.lease_valid and lease != 0:
                with self._lock:
                    if self.lease == lease:
                        self.lease = 0
                        self.lease_lost.set()
                        if r.lease_lost_reason:
                            # e.g. one of its step records was refused: the episode cannot complete.
                            self.log(f"actor {self.rank}: lease {lease} ended by the learner: {r.lease_lost_reason}")
            if r.shutdown:
                self.shutdown.set()

    def _watch(self):
        have = 0
        while not self._stop.is_set():
            try:
                self._watch_call = self.conn.watch(pb.PolicyRequest(run=self.run, actor_id=self.actor_id, have_version=have,
                                                                   actor_secret=self.secret))
                for snap in self._watch_call:
                    net = MlpPolicy(self.info.policy_dims, snap.weights)
                    with self._policy_cv:
                        self._policy = (snap.version, snap.exploration_sigma, net)
                        self._policy_cv.notify_all()
                    have = snap.version
                return
            except grpc.RpcError as e:
                if self._stop.is_set():
                    return
                with self._policy_cv:
                    self._policy_error = f"policy stream: {e.code().name}: {e.details()}"
                    self._policy_cv.notify_all()
                return
            except Exception as e:  # a malformed snapshot
                with self._policy_cv:
                    self._policy_error = f"policy snapshot: {e}"
                    self._policy_cv.notify_all()
                return

    # -- API ------------------------------------------------------------------------------
    def next_assignment(self):
        """Asks for work: returns a `pb.Assignment`, an idle time in ms (int), or None when
        the run is over. Raises `_Reconnect` when the learner refuses the session."""
        try:
            r = self.conn.call(
                self.conn.control.NextAssignment,
                pb.AssignmentRequest(run=self.run, actor_id=self.actor_id, actor_secret=self.secret),
                timeout=30.0,
            )
        except grpc.RpcError as e:
            raise _Reconnect(f"next assignment: {e.code().name}: {e.details()}") from e
        which = r.WhichOneof("decision")
        if which == "shutdown":
            return None
        if which == "idle_ms":
            return max(r.idle_ms, 1)
        if which == "assign":
            with self._lock:
                self.lease = r.assign.lease_id
                self.lease_lost.clear()
            return r.assign
        raise _Reconnect("empty assignment reply")

    def wait_policy(self, version: int):
        """Blocks until a policy of at least `version` arrived; returns (version, sigma, net),
        or None if the lease was lost meanwhile."""
        with self._policy_cv:
            while True:
                if self._policy is not None and self._policy[0] >= version:
                    return self._policy
                if self._policy_error is not None:
                    raise _Reconnect(self._policy_error)
                if self.lease_lost.is_set() or self.gone.is_set():
                    return None
                self._policy_cv.wait(0.05)

    def send(self, lease_id: int, record: pb.StepRecord):
        """Queues one step record; sends a batch of BATCH_RECORDS."""
        if self._batch and (self._batch_lease != lease_id or len(self._batch) >= BATCH_RECORDS):
            self.flush()
        self._batch_lease = lease_id
        self._batch.append(record)

    def flush(self):
        """Sends the queued records. Raises `StepsRefused` when the learner refuses any and
        `_Reconnect` when the call fails."""
        if not self._batch:
            return
        batch = pb.StepBatch(run=self.run, actor_id=self.actor_id, lease_id=self._batch_lease, steps=self._batch,
                             actor_secret=self.secret)
        n = len(self._batch)
        self._batch = []
        try:
            ack = self.conn.push(batch)
        except grpc.RpcError as e:
            raise _Reconnect(f"push steps: {e.code().name}: {e.details()}") from e
        if ack.refused:
            raise StepsRefused(ack.refused, n, ack.reason)

    def report(self, report: pb.EpisodeReport) -> bool:
        """Reports an episode; False when its lease expired meanwhile (NOT_FOUND)."""
        report.run.CopyFrom(self.run)
        report.actor_id = self.actor_id
        report.actor_secret = self.secret
        try:
            self.conn.call(self.conn.control.ReportEpisode, report, timeout=30.0)
        except grpc.RpcError as e:
            if e.code() == grpc.StatusCode.NOT_FOUND:
                return False
            raise _Reconnect(f"episode report: {e.code().name}: {e.details()}") from e
        return True

    def wait_lease_end(self, limit: float):
        """Keeps heartbeating until the learner has finished or dropped the current lease."""
        end = time.monotonic() + limit
        while time.monotonic() < end and not self.gone.is_set():
            with self._lock:
                if self.lease == 0:
                    return
            time.sleep(0.01)

    def close(self):
        """Stops the heartbeat and policy threads."""
        self._stop.set()
        if self._watch_call is not None:
            self._watch_call.cancel()
        self._hb.join(timeout=5)
        self._pw.join(timeout=5)


class Environment:
    """What a simulator implements to train with the learner (gymnasium-style).

    `configure(info)` is called once per session with the run's settings (`RunInfo`: obs and
    action sizes, action space, planner, `env`). `reset(world, seed)` starts an episode
    in BARN world `world` and returns the first observation (`obs_dim` floats). `step(action)`
    applies a normalized action in [-1, 1]^act_dim and returns `(obs, reward, terminal,
    truncated, info)`; when the episode ends, `info` carries `outcome` ("success",
    "collision" or "timeout"), `time_s` (BARN clock) and `score`.
    """

    def configure(self, info: RunInfo) -> None:
        """Receives the run's settings (optional)."""

    def reset(self, world: int, seed: int):
        """Starts an episode; returns the first observation."""
        raise NotImplementedError

    def step(self, action):
        """Applies `action`; returns (obs, reward, terminal, truncated, info)."""
        raise NotImplementedError


def _stderr_log(line: str):
    sys.stderr.write(line + "\n")
    sys.stderr.flush()


class Actor:
    """A Python actor of an adp run: `Actor(address, env, ...).run()` trains until the learner
    says the run is over.

    `env` is an `Environment` (or anything with its methods). Connection settings as
    `Connection`. `give_up_after` (s): raise `LearnerUnreachable` when no session could be
    opened for that long.
    """

    def __init__(self, address, env, rank=0, token=None, token_file=None, tls_ca=None, tls_cert=None,
                 tls_key=None, tls_domain=None, give_up_after=60.0, log=_stderr_log):
        self.address = address
        self.env = env
        self.rank = rank
        self._conn_args = dict(token=token, token_file=token_file, tls_ca=tls_ca, tls_cert=tls_cert,
                               tls_key=tls_key, tls_domain=tls_domain)
        if token is None and token_file is not None:
            read_token_file(token_file)  # fail early with a clear message
        self.give_up_after = give_up_after
        self.log = log
        self.episodes = 0
        self.sessions = 0
        self.leases_lost = 0

    def run(self) -> None:
        """Runs until the run is over; re-registers with back-off after a learner restart or
        a lost session."""
        wait = 0.2
        down_since = None
        previous = None
        while True:
            conn = Connection(self.address, **self._conn_args)
            try:
                try:
                    session = Session(conn, self.rank, self.log, previous)
                except grpc.RpcError as e:
                    if e.code() == grpc.StatusCode.UNAUTHENTICATED:
                        raise ConfigError(f"learner at {self.address} refused the token: {e.details()}") from e
                    why = f"register: {e.code().name}: {e.details()}"
                else:
                    down_since = None
                    wait = 0.2
                    self.sessions += 1
                    previous = (session.actor_id, session.secret)
                    try:
                        if self._session(session):
                            return
                        why = "session ended"
                    except _Reconnect as e:
                        why = str(e)
                    finally:
                        session.close()
            finally:
                conn.close()
            if down_since is None:
                down_since = time.monotonic()
            if time.monotonic() - down_since > self.give_up_after:
                raise LearnerUnreachable(
                    f"actor rank {self.rank}: learner at {self.address} unreachable for "
                    f"{time.monotonic() - down_since:.1f} s: {why}"
                )
            self.log(f"actor {self.rank}: {why}; reconnecting in {wait:.1f} s")
            time.sleep(wait)
            wait = min(wait * 2, 5.0)

    def _session(self, s: Session) -> bool:
        info = s.info
        if hasattr(self.env, "configure"):
            self.env.configure(info)
        self.log(f"actor {self.rank}: registered as {info.actor_id} with run {info.run_id} "
                 f"({info.planner}, {info.action_space.name}, python)")
        while True:
            if s.shutdown.is_set():
                s.wait_lease_end(self.give_up_after)
                return True
            if s.gone.is_set():
                raise _Reconnect("the learner no longer knows this session, or stopped answering heartbeats")
            a = s.next_assignment()
            if a is None:
                s.wait_lease_end(self.give_up_after)
                return True
            if isinstance(a, int):
                time.sleep(a / 1000.0)
                continue
            pol = s.wait_policy(a.policy_version)
            if pol is None:
                continue
            for i in range(a.episodes):
                if s.lease_lost.is_set():
                    break
                seed = a.seeds[i] if i < len(a.seeds) else a.lease_id
                episode_id = a.first_episode_id + i
                try:
                    report = self._episode(s, a, episode_id, seed, pol)  # None: lease lost
                    # Send what waits; after a lost lease the learner refuses and counts it.
                    s.flush()
                except StepsRefused as e:
                    self._refused(s, a, e)
                    report = None
                if report is None:
                    self.leases_lost += 1
                    break
                report.lease_id = a.lease_id
                report.last_of_assignment = i + 1 == a.episodes
                report.policy_version = pol[0]
                if not s.report(report):
                    self.leases_lost += 1
                    break
                self.episodes += 1

    def _refused(self, s: Session, a, e: StepsRefused):
        """Decides what a refusal means: the lease or session ended (drop the assignment, or
        register again), or records this client made wrongly (a fatal error)."""
        if s.lease_lost.is_set() or e.reason.startswith(f"lease {a.lease_id}:"):
            self.log(f"actor {self.rank}: lease {a.lease_id} lost; {e}")
            return
        if s.gone.is_set() or e.reason.startswith(("stale incarnation", "wrong run", "actor ")):
            raise _Reconnect(str(e))
        raise e

    def _episode(self, s: Session, a, episode_id, seed, pol):
        version, sigma, net = pol
        info = s.info
        rng = np.random.default_rng(exploration_seed(seed))
        obs = self._obs(self.env.reset(a.world, seed), info.obs_dim, "reset")
        obs_b = ck.f32_bytes(obs)
        total = 0
        index = 0
        ret = 0.0
        while True:
            if s.lease_lost.is_set():
                return None
            action = net.act(obs)
            if sigma > 0:
                action = action.astype(np.float64) + sigma * rng.standard_normal(action.shape)
            action = np.clip(action, -1.0, 1.0).astype(np.float32)
            out = self.env.step(action.copy())
            if not (isinstance(out, tuple) and len(out) == 5):
                raise EnvironmentFault("env.step must return (obs, reward, terminal, truncated, info)")
            nxt, reward, terminal, truncated, einfo = out
            nxt = self._obs(nxt, info.obs_dim, "step")
            reward = float(np.float32(reward))
            if not np.isfinite(reward):
                raise EnvironmentFault(f"env.step returned reward {reward}: must be finite")
            terminal, truncated = bool(terminal), bool(truncated) and not bool(terminal)
            act_b = ck.f32_bytes(action)
            fin_b = ck.f32_bytes(nxt) if truncated else b""
            rec = pb.StepRecord(episode_id=episode_id, step_index=index, policy_version=version, obs=obs_b,
                                action=act_b, reward=reward, terminal=terminal, truncated=truncated, final_obs=fin_b)
            s.send(a.lease_id, rec)
            total = ck.add(total, ck.step_checksum(episode_id, index, version, obs_b, act_b, reward, terminal,
                                                   truncated, fin_b))
            index += 1
            ret += reward
            if terminal or truncated:
                break
            obs, obs_b = nxt, ck.f32_bytes(nxt)
        einfo = einfo or {}
        outcome = einfo.get("outcome", "timeout")
        if outcome not in OUTCOMES:
            raise EnvironmentFault(f"info['outcome'] = {outcome!r}: expected success, collision or timeout")
        return pb.EpisodeReport(episode_id=episode_id, world=a.world, outcome=OUTCOMES[outcome],
                                time_s=float(einfo.get("time_s", 0.0)), score=float(einfo.get("score", 0.0)),
                                episode_return=ret, steps=index, steps_checksum=total)

    @staticmethod
    def _obs(obs, dim, where):
        o = np.asarray(obs, dtype=np.float32).ravel()
        if o.size != dim:
            raise EnvironmentFault(f"env.{where} returned an observation of {o.size} values; the run needs {dim}")
        if not np.all(np.isfinite(o)):
            raise EnvironmentFault(f"env.{where} returned a non-finite observation value")
        return o
