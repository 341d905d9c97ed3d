//! A local supervisor of actor processes: spawns them in a [`Sandbox`], reaps them, restarts
//! crashed ones with back-off, and stops them (Linux only).
//!
//! Time for restart decisions is passed in (`now: Instant`), so callers and tests drive it;
//! only [`Supervisor::shutdown`] waits in real time (its grace period).

use std::io;
use std::os::unix::process::ExitStatusExt;
use std::path::PathBuf;
use std::process::{Child, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use crate::backoff::{Backoff, BackoffPolicy};
use crate::sandbox::{BwrapStatus, Sandbox};

/// Per-rank launch details: extra arguments (appended to the template's) and environment
/// variables of actor `rank`.
pub type RankLaunch = dyn Fn(u32) -> (Vec<String>, Vec<(String, String)>) + Send;

/// What to run.
#[derive(Debug, Clone, PartialEq)]
pub struct SupervisorConfig {
    /// The actor executable.
    pub program: PathBuf,
    /// Arguments common to all actors.
    pub args: Vec<String>,
    /// Number of actors; ranks are `0..actors`.
    pub actors: u32,
    /// Restart back-off of crashed actors.
    pub backoff: BackoffPolicy,
}

/// How a child ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExitKind {
    /// It exited with this status code.
    Code(i32),
    /// It was killed by this signal.
    Signal(i32),
}

impl ExitKind {
    fn of(status: ExitStatus) -> Self {
        match (status.code(), status.signal()) {
            (Some(code), _) => Self::Code(code),
            (None, Some(signal)) => Self::Signal(signal),
            (None, None) => unreachable!("a reaped child exited or was killed: {status:?}"),
        }
    }
}

/// Something that happened to a child, from [`Supervisor::poll`] or [`Supervisor::shutdown`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SupervisorEvent {
    /// The child of `rank` ended. A crash (non-zero code or a signal) is restarted after
    /// `restart_in_ms`; an exit with code 0, or an end during shutdown, is not (`None`).
    Exited {
        /// The actor rank.
        rank: u32,
        /// The pid of the ended child.
        pid: u32,
        /// How it ended.
        exit: ExitKind,
        /// The restart delay, if it will be restarted.
        restart_in_ms: Option<u64>,
    },
    /// A crashed child of `rank` was started again.
    Restarted {
        /// The actor rank.
        rank: u32,
        /// The pid of the new child.
        pid: u32,
    },
    /// Starting a crashed child again failed; it is retried after `restart_in_ms`.
    RestartFailed {
        /// The actor rank.
        rank: u32,
        /// Why the spawn failed.
        error: String,
        /// The delay before the next attempt.
        restart_in_ms: u64,
    },
}

/// Why a supervisor operation failed.
#[derive(Debug, thiserror::Error)]
pub enum SupervisorError {
    /// The configuration is unusable.
    #[error("invalid supervisor configuration: {0}")]
    InvalidConfig(String),
    /// An actor could not be started at [`Supervisor::start`].
    #[error("cannot start actor rank {rank} ({program}): {source}")]
    Spawn {
        /// The actor rank.
        rank: u32,
        /// The program.
        program: PathBuf,
        /// The spawn error.
        source: io::Error,
    },
    /// [`Supervisor::kill`] for a rank without a running child.
    #[error("actor rank {rank} has no running process")]
    NotRunning {
        /// The actor rank.
        rank: u32,
    },
    /// Sending a signal failed.
    #[error("cannot send signal {signal} to actor rank {rank} (pid {pid}): {source}")]
    Signal {
        /// The actor rank.
        rank: u32,
        /// The child's pid.
        pid: u32,
        /// The signal.
        signal: i32,
        /// The error of `killpg`.
        source: io::Error,
    },
}

enum Slot {
    Running {
        child: Child,
        started: Instant,
    },
    RestartAt(Instant),
    /// Exited with code 0, or stopped by shutdown: never restarted.
    Done,
}

/// Marks the slot of `rank` done after a stop and the event that reports it (a child ended
/// by a stop is never restarted).
fn stopped(slot: &mut Slot, rank: u32, pid: u32, exit: ExitKind) -> SupervisorEvent {
    *slot = Slot::Done;
    SupervisorEvent::Exited {
        rank,
        pid,
        exit,
        restart_in_ms: None,
    }
}

/// Owns the actor processes of one node.
///
/// Children die with the *thread* that spawned them (`PR_SET_PDEATHSIG`), and restarts spawn
/// from the thread calling [`Supervisor::poll`]: drive a supervisor from one long-lived thread
/// (e.g. the main thread). It is `Send`, not `Sync`. Dropping it kills (`SIGKILL`) and reaps
/// all children; [`Supervisor::shutdown`] stops them gracefully.
pub struct Supervisor {
    sandbox: Sandbox,
    config: SupervisorConfig,
    launch: Box<RankLaunch>,
    slots: Vec<(Slot, Backoff)>,
}

impl Supervisor {
    /// Starts `config.actors` children `program args extra_args` with `launch(rank)` giving
    /// each rank's extra arguments and environment, in `sandbox`, with standard input from
    /// `/dev/null` and standard output and error inherited. If one fails to start, those
    /// already started are killed and the error is returned.
    pub fn start(
        config: SupervisorConfig,
        sandbox: Sandbox,
        launch: impl Fn(u32) -> (Vec<String>, Vec<(String, String)>) + Send + 'static,
        now: Instant,
    ) -> Result<Self, SupervisorError> {
        if !config.backoff.is_valid() {
            return Err(SupervisorError::InvalidConfig(format!(
                "back-off needs a finite factor >= 1 and base <= max, got {:?}",
                config.backoff
            )));
        }
        let slots = (0..config.actors)
            .map(|_| (Slot::Done, Backoff::new(config.backoff)))
            .collect();
        let mut supervisor = Self {
            sandbox,
            config,
            launch: Box::new(launch),
            slots,
        };
        for rank in 0..supervisor.config.actors {
            let child = supervisor.spawn(rank).map_err(|source| SupervisorError::Spawn {
                rank,
                program: supervisor.config.program.clone(),
                source,
            })?;
            supervisor.slots[rank as usize].0 = Slot::Running { child, started: now };
        }
        Ok(supervisor)
    }

    /// Whether the children run under bubblewrap.
    pub fn bwrap_status(&self) -> &BwrapStatus {
        self.sandbox.bwrap_status()
    }

    /// The pid of the running child of `rank`, if any.
    pub fn pid(&self, rank: u32) -> Option<u32> {
        match self.slots.get(rank as usize) {
            Some((Slot::Running { child, .. }, _)) => Some(child.id()),
            _ => None,
        }
    }

    /// Sends `signal` (e.g. `libc::SIGKILL`, `SIGSTOP`, `SIGCONT`) to the process group of
    /// the running child of `rank` (the child and any processes it started).
    pub fn kill(&self, rank: u32, signal: i32) -> Result<(), SupervisorError> {
        let pid = self.pid(rank).ok_or(SupervisorError::NotRunning { rank })?;
        signal_group(pid, signal).map_err(|source| SupervisorError::Signal {
            rank,
            pid,
            signal,
            source,
        })
    }

    /// Reaps ended children and starts due restarts, at time `now`. A crash schedules a
    /// restart after the rank's back-off delay (the run length `now - start` decides whether
    /// the back-off resets); an exit with code 0 ends the rank for good. When a child ends,
    /// the rest of its process group is killed before it is reaped.
    pub fn poll(&mut self, now: Instant) -> Vec<SupervisorEvent> {
        let mut events = Vec::new();
        for rank in 0..self.config.actors {
            let (slot, backoff) = &mut self.slots[rank as usize];
            match slot {
                Slot::Running { child, started } => {
                    let Some(status) = reap_if_exited(child) else {
                        continue;
                    };
                    let (pid, exit) = (child.id(), ExitKind::of(status));
                    let restart_in = (!status.success())
                        .then(|| backoff.on_crash(now.saturating_duration_since(*started)));
                    *slot = restart_in.map_or(Slot::Done, |delay| Slot::RestartAt(now + delay));
                    let restart_in_ms = restart_in.map(|delay| delay.as_millis() as u64);
                    events.push(SupervisorEvent::Exited {
                        rank,
                        pid,
                        exit,
                        restart_in_ms,
                    });
                }
                Slot::RestartAt(at) if now >= *at => match self.spawn(rank) {
                    Ok(child) => {
                        events.push(SupervisorEvent::Restarted {
                            rank,
                            pid: child.id(),
                        });
                        self.slots[rank as usize].0 = Slot::Running { child, started: now };
                    }
                    Err(error) => {
                        let (slot, backoff) = &mut self.slots[rank as usize];
                        let delay = backoff.on_crash(Duration::ZERO);
                        *slot = Slot::RestartAt(now + delay);
                        let (error, restart_in_ms) = (error.to_string(), delay.as_millis() as u64);
                        events.push(SupervisorEvent::RestartFailed {
                            rank,
                            error,
                            restart_in_ms,
                        });
                    }
                },
                Slot::RestartAt(_) | Slot::Done => {}
            }
        }
        events
    }

    /// Stops all children: `SIGTERM` to each child's process group, up to `grace` (real
    /// time) for them to end, then `SIGKILL`; reaps all and cancels pending restarts. Returns
    /// the exits (all with `restart_in_ms: None`). Later calls to `poll` do nothing.
    pub fn shutdown(&mut self, grace: Duration) -> Vec<SupervisorEvent> {
        let deadline = Instant::now() + grace;
        for (slot, _) in &mut self.slots {
            match slot {
                Slot::Running { child, .. } => {
                    let _ = signal_group(child.id(), libc::SIGTERM);
                }
                Slot::RestartAt(_) => *slot = Slot::Done,
                Slot::Done => {}
            }
        }
        let mut events = Vec::new();
        loop {
            for (rank, (slot, _)) in (0..).zip(&mut self.slots) {
                if let Slot::Running { child, .. } = slot {
                    if let Some(status) = reap_if_exited(child) {
                        let (pid, exit) = (child.id(), ExitKind::of(status));
                        events.push(stopped(slot, rank, pid, exit));
                    }
                }
            }
            let running = self
                .slots
                .iter()
                .any(|(slot, _)| matches!(slot, Slot::Running { .. }));
            if !running || Instant::now() >= deadline {
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        for (rank, (slot, _)) in (0..).zip(&mut self.slots) {
            if let Slot::Running { child, .. } = slot {
                let pid = child.id();
                let exit = ExitKind::of(kill_and_reap(child));
                events.push(stopped(slot, rank, pid, exit));
            }
        }
        events
    }

    fn spawn(&self, rank: u32) -> io::Result<Child> {
        let (extra_args, env) = (self.launch)(rank);
        let args = [self.config.args.as_slice(), extra_args.as_slice()].concat();
        self.sandbox
            .command(&self.config.program, &args)
            .envs(env)
            .stdin(Stdio::null())
            .spawn()
    }
}

impl Drop for Supervisor {
    /// Kills (`SIGKILL`) and reaps every running child with its process group.
    fn drop(&mut self) {
        for (slot, _) in &mut self.slots {
            if let Slot::Running { child, .. } = slot {
                kill_and_reap(child);
            }
        }
    }
}

/// `killpg(pid, signal)`: the child leads its own process group.
fn signal_group(pid: u32, signal: i32) -> io::Result<()> {
    // SAFETY: a plain system call.
    if unsafe { libc::killpg(pid as libc::pid_t, signal) } != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// If `child` has ended: kills what is left of its process group and reaps it. While the
/// ended child is not reaped its pid, and so its process group id, cannot be reused, so the
/// group kill cannot hit an unrelated process.
fn reap_if_exited(child: &mut Child) -> Option<ExitStatus> {
    // SAFETY: zeroed `siginfo_t` is a valid value; waitid writes into it.
    let mut info: libc::siginfo_t = unsafe { std::mem::zeroed() };
    let flags = libc::WEXITED | libc::WNOHANG | libc::WNOWAIT;
    // SAFETY: `info` is valid and writable; WNOWAIT leaves the child waitable.
    let peeked = unsafe { libc::waitid(libc::P_PID, child.id() as libc::id_t, &mut info, flags) };
    // SAFETY: after a successful waitid the pid field is initialized (0 if nothing ended).
    if peeked == 0 && unsafe { info.si_pid() } == 0 {
        return None;
    }
    if peeked == 0 {
        let _ = signal_group(child.id(), libc::SIGKILL);
    }
    // If waitid failed (e.g. the child was reaped behind our back), std reports it.
    child.try_wait().ok().flatten()
}

/// Kills the child's process group and waits for the child.
fn kill_and_reap(child: &mut Child) -> ExitStatus {
    let _ = signal_group(child.id(), libc::SIGKILL);
    child.wait().expect("waiting for a killed child")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sandbox::{BwrapMode, SandboxConfig};
    use crate::test_util::TempDir;
    use std::path::Path;

    /// Upper bound on polls while waiting for real processes (a watchdog, not a time limit).
    const MAX_POLLS: usize = 20_000;

    fn sandbox() -> Sandbox {
        Sandbox::new(SandboxConfig {
            bwrap: BwrapMode::Off,
            ..SandboxConfig::default()
        })
        .unwrap()
    }

    fn shell(script: &str, actors: u32) -> SupervisorConfig {
        SupervisorConfig {
            program: "/bin/sh".into(),
            args: vec!["-c".into(), script.into(), "sh".into()],
            actors,
            backoff: BackoffPolicy::default(),
        }
    }

    fn no_extras(_: u32) -> (Vec<String>, Vec<(String, String)>) {
        (Vec::new(), Vec::new())
    }

    /// Polls at the fixed logical time `now` until at least `count` events arrived.
    fn wait_events(supervisor: &mut Supervisor, now: Instant, count: usize) -> Vec<SupervisorEvent> {
        let mut events = Vec::new();
        for _ in 0..MAX_POLLS {
            events.extend(supervisor.poll(now));
            if events.len() >= count {
                return events;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        panic!("only {events:?} after {MAX_POLLS} polls");
    }

    #[test]
    fn crashing_child_restarts_with_growing_back_off() {
        let mut now = Instant::now();
        let mut supervisor = Supervisor::start(shell("exit 3", 1), sandbox(), no_extras, now).unwrap();
        for expected_ms in [500, 1_000, 2_000] {
            let pid = supervisor.pid(0).unwrap();
            let exit = ExitKind::Code(3);
            let events = wait_events(&mut supervisor, now, 1);
            assert_eq!(
                events,
                [SupervisorEvent::Exited {
                    rank: 0,
                    pid,
                    exit,
                    restart_in_ms: Some(expected_ms)
                }]
            );
            assert_eq!(supervisor.pid(0), None);
            assert!(supervisor
                .poll(now + Duration::from_millis(expected_ms - 1))
                .is_empty());
            now += Duration::from_millis(expected_ms);
            let events = supervisor.poll(now);
            let pid = supervisor.pid(0).expect("restarted");
            assert_eq!(events, [SupervisorEvent::Restarted { rank: 0, pid }]);
        }
        supervisor.shutdown(Duration::ZERO);
    }

    #[test]
    fn a_long_run_resets_the_back_off() {
        let start = Instant::now();
        let mut supervisor = Supervisor::start(shell("exit 1", 1), sandbox(), no_extras, start).unwrap();
        let events = wait_events(&mut supervisor, start, 1);
        assert!(matches!(
            events[0],
            SupervisorEvent::Exited {
                restart_in_ms: Some(500),
                ..
            }
        ));
        let restart = start + Duration::from_millis(500);
        assert_eq!(supervisor.poll(restart).len(), 1);
        let later = restart + Duration::from_secs(61);
        let events = wait_events(&mut supervisor, later, 1);
        assert!(
            matches!(
                events[0],
                SupervisorEvent::Exited {
                    restart_in_ms: Some(500),
                    ..
                }
            ),
            "{events:?}"
        );
    }

    #[test]
    fn child_exiting_zero_is_not_restarted() {
        let now = Instant::now();
        let mut supervisor = Supervisor::start(shell("exit 0", 2), sandbox(), no_extras, now).unwrap();
        let pids = [supervisor.pid(0).unwrap(), supervisor.pid(1).unwrap()];
        let mut events = wait_events(&mut supervisor, now, 2);
        events.sort_by_key(|event| match event {
            SupervisorEvent::Exited { rank, .. } => *rank,
            other => panic!("unexpected {other:?}"),
        });
        let expected: Vec<SupervisorEvent> = (0..2)
            .map(|rank| SupervisorEvent::Exited {
                rank,
                pid: pids[rank as usize],
                exit: ExitKind::Code(0),
                restart_in_ms: None,
            })
            .collect();
        assert_eq!(events, expected);
        assert!(supervisor.poll(now + Duration::from_secs(3_600)).is_empty());
        assert_eq!((supervisor.pid(0), supervisor.pid(1)), (None, None));
    }

    #[test]
    fn children_see_the_sandbox_limits_and_their_launch_details() {
        let dir = TempDir::new("supervisor-limits");
        let sandbox = Sandbox::new(SandboxConfig {
            bwrap: BwrapMode::Off,
            open_files: 64,
            ..SandboxConfig::default()
        })
        .unwrap();
        let script = "{ ulimit -n; ulimit -c; ulimit -v; echo \"$ACTOR_RANK $2\"; } > \"$1/out-$ACTOR_RANK\"";
        let dir_arg = dir.path().display().to_string();
        let launch = move |rank: u32| {
            (
                vec![dir_arg.clone(), format!("arg{rank}")],
                vec![("ACTOR_RANK".to_string(), rank.to_string())],
            )
        };
        let now = Instant::now();
        let mut supervisor = Supervisor::start(shell(script, 2), sandbox, launch, now).unwrap();
        let events = wait_events(&mut supervisor, now, 2);
        assert!(events.iter().all(|event| matches!(
            event,
            SupervisorEvent::Exited {
                exit: ExitKind::Code(0),
                ..
            }
        )));
        for rank in 0..2 {
            let out = std::fs::read_to_string(dir.path().join(format!("out-{rank}"))).unwrap();
            assert_eq!(out, format!("64\n0\n{}\n{rank} arg{rank}\n", 4 << 20));
        }
    }

    #[test]
    fn kill_signals_the_child_and_the_crash_is_restarted() {
        let now = Instant::now();
        let mut supervisor = Supervisor::start(shell("sleep 1000", 1), sandbox(), no_extras, now).unwrap();
        let pid = supervisor.pid(0).unwrap();
        supervisor.kill(0, libc::SIGSTOP).unwrap();
        supervisor.kill(0, libc::SIGCONT).unwrap();
        assert!(
            supervisor.poll(now).is_empty(),
            "stopped and continued, not ended"
        );
        supervisor.kill(0, libc::SIGKILL).unwrap();
        let events = wait_events(&mut supervisor, now, 1);
        let exit = ExitKind::Signal(libc::SIGKILL);
        assert_eq!(
            events,
            [SupervisorEvent::Exited {
                rank: 0,
                pid,
                exit,
                restart_in_ms: Some(500)
            }]
        );
        assert!(matches!(
            supervisor.kill(0, libc::SIGKILL),
            Err(SupervisorError::NotRunning { rank: 0 })
        ));
        assert!(matches!(
            supervisor.kill(5, libc::SIGKILL),
            Err(SupervisorError::NotRunning { rank: 5 })
        ));
    }

    #[test]
    fn processes_left_behind_by_an_ended_child_are_killed() {
        let dir = TempDir::new("supervisor-orphans");
        let script = "sleep 1000 & echo $! > \"$1/orphan\"; exit 3";
        let dir_arg = dir.path().display().to_string();
        let now = Instant::now();
        let launch = move |_| (vec![dir_arg.clone()], Vec::new());
        let mut supervisor = Supervisor::start(shell(script, 1), sandbox(), launch, now).unwrap();
        wait_events(&mut supervisor, now, 1);
        let orphan = std::fs::read_to_string(dir.path().join("orphan")).unwrap();
        let stat = Path::new("/proc").join(orphan.trim()).join("stat");
        let gone = (0..MAX_POLLS).any(|_| {
            // Gone, or a zombie waiting for its new parent to reap it.
            let ended = std::fs::read_to_string(&stat).map_or(true, |stat| stat.contains(") Z "));
            if !ended {
                std::thread::sleep(Duration::from_millis(1));
            }
            ended
        });
        assert!(gone, "the orphaned sleep {} survived", orphan.trim());
    }

    #[test]
    fn shutdown_terminates_then_kills() {
        let now = Instant::now();
        let mut supervisor = Supervisor::start(shell("sleep 1000", 1), sandbox(), no_extras, now).unwrap();
        let pid = supervisor.pid(0).unwrap();
        let events = supervisor.shutdown(Duration::from_secs(600));
        let exit = ExitKind::Signal(libc::SIGTERM);
        assert_eq!(
            events,
            [SupervisorEvent::Exited {
                rank: 0,
                pid,
                exit,
                restart_in_ms: None
            }]
        );
        assert_eq!(supervisor.pid(0), None);
        assert!(supervisor.poll(now + Duration::from_secs(3_600)).is_empty());

        let dir = TempDir::new("supervisor-stubborn");
        let ready = dir.path().join("ready");
        let stubborn = shell("trap '' TERM; : > \"$1\"; sleep 1000", 1);
        let ready_arg = ready.display().to_string();
        let launch = move |_| (vec![ready_arg.clone()], Vec::new());
        let mut supervisor = Supervisor::start(stubborn, sandbox(), launch, now).unwrap();
        let pid = supervisor.pid(0).unwrap();
        let trapped = (0..MAX_POLLS).any(|_| {
            let exists = ready.exists();
            if !exists {
                std::thread::sleep(Duration::from_millis(1));
            }
            exists
        });
        assert!(trapped, "the child never got to ignore SIGTERM");
        let events = supervisor.shutdown(Duration::ZERO);
        let exit = ExitKind::Signal(libc::SIGKILL);
        assert_eq!(
            events,
            [SupervisorEvent::Exited {
                rank: 0,
                pid,
                exit,
                restart_in_ms: None
            }]
        );
    }

    #[test]
    fn children_die_with_the_spawning_thread() {
        let pid = std::thread::spawn(|| {
            let supervisor =
                Supervisor::start(shell("sleep 1000", 1), sandbox(), no_extras, Instant::now()).unwrap();
            let pid = supervisor.pid(0).unwrap();
            // Neither kill nor reap: only PR_SET_PDEATHSIG can end the child.
            std::mem::forget(supervisor);
            pid
        })
        .join()
        .unwrap();
        let mut status = 0;
        let reaped = (0..MAX_POLLS).any(|_| {
            // SAFETY: `status` is valid and writable; the child is ours and not yet reaped.
            let reaped = unsafe { libc::waitpid(pid as libc::pid_t, &mut status, libc::WNOHANG) } != 0;
            if !reaped {
                std::thread::sleep(Duration::from_millis(1));
            }
            reaped
        });
        assert!(reaped, "the child {pid} outlived the thread that spawned it");
        assert!(
            libc::WIFSIGNALED(status) && libc::WTERMSIG(status) == libc::SIGKILL,
            "status {status:#x}"
        );
    }

    #[test]
    fn start_rejects_a_bad_back_off_and_a_missing_program() {
        let mut config = shell("exit 0", 1);
        config.backoff.factor = 0.0;
        let error = Supervisor::start(config, sandbox(), no_extras, Instant::now())
            .err()
            .unwrap();
        assert!(matches!(error, SupervisorError::InvalidConfig(_)), "{error}");
        let config = SupervisorConfig {
            program: "/nonexistent/actor".into(),
            ..shell("", 1)
        };
        let error = Supervisor::start(config, sandbox(), no_extras, Instant::now())
            .err()
            .unwrap();
        assert!(error.to_string().contains("/nonexistent/actor"), "{error}");
    }

    #[test]
    fn auto_mode_without_bwrap_runs_children_directly() {
        let empty = TempDir::new("supervisor-no-bwrap");
        let config = SandboxConfig {
            bwrap: BwrapMode::Auto,
            ..SandboxConfig::default()
        };
        let sandbox = Sandbox::with_search_path(config, Some(empty.path().as_os_str())).unwrap();
        let now = Instant::now();
        let mut supervisor = Supervisor::start(shell("exit 0", 1), sandbox, no_extras, now).unwrap();
        assert!(matches!(supervisor.bwrap_status(), BwrapStatus::Unavailable(_)));
        let events = wait_events(&mut supervisor, now, 1);
        assert!(matches!(
            events[0],
            SupervisorEvent::Exited {
                exit: ExitKind::Code(0),
                ..
            }
        ));
    }
}
