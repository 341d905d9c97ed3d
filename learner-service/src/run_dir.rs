//! The run directory a learner serves: its files (address, socket, operator token, lock), the
//! lock that keeps a second learner out, and what a starting learner finds in it (a fresh run,
//! or the checkpoints to resume from).

use std::path::{Path, PathBuf};

use learner::ddp_init::FitOptions;
use learner::rate::RateLimiter;
use learner::replay::ReplayBuffer;
use learner::retention;
use learner::td3::{seeded_rng, Td3};
use scheduler::{Registry, RegistryConfig};

use crate::config::{LearnerOptions, StartAction};
use crate::error::{FileError, ResumeError, StartError};
use crate::resume::{newest_usable, TrainingState};
use crate::status::ResumeStatus;
use crate::totals::Totals;

/// File in the run directory holding the learner's bound `host:port`.
pub const ADDR_FILE: &str = "learner.addr";

/// The learner's Unix socket in the run directory (same services as the TCP address).
pub const SOCKET_FILE: &str = "learner.sock";

/// File in the run directory (mode 0600) holding the operator credential that `Shutdown`
/// needs besides the run token; made at the first start and kept across resumes. Actors are
/// never given it.
pub const OPERATOR_TOKEN_FILE: &str = "operator.token";

/// The lock file a learner holds in its run directory.
pub const LOCK_FILE: &str = "learner.lock";

/// Takes the run directory's lock (an exclusive `flock` on `learner.lock`, which also records
/// the holder's host and pid). Refused while another learner process holds it, so a second
/// learner can never remove the first one's socket or write into its checkpoints. The lock
/// goes away with the process, also when it is killed.
pub fn lock_run_dir(run_dir: &Path) -> Result<std::fs::File, StartError> {
    use std::io::{Read, Seek, Write};
    use std::os::unix::fs::OpenOptionsExt;
    let path = run_dir.join(LOCK_FILE);
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .mode(0o600)
        .open(&path)
        .map_err(FileError::at(format!(
            "cannot open the lock file {}",
            path.display()
        )))?;
    match file.try_lock() {
        Ok(()) => {
            let holder = format!("{} pid {}\n", proto::hostname(), std::process::id());
            let _ = file
                .set_len(0)
                .and_then(|()| file.rewind())
                .and_then(|()| file.write_all(holder.as_bytes()));
            Ok(file)
        }
        Err(std::fs::TryLockError::WouldBlock) => {
            let mut holder = String::new();
            let _ = file.read_to_string(&mut holder);
            Err(StartError::InUse {
                run_dir: run_dir.to_path_buf(),
                holder: holder.trim().to_string(),
                lock: path,
            })
        }
        Err(std::fs::TryLockError::Error(e)) => {
            Err(FileError::at(format!("cannot lock {}", path.display()))(e).into())
        }
    }
}

/// Writes `text` to `path` atomically.
pub(crate) fn write_atomic(path: &Path, text: &str) -> Result<(), FileError> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, text)
        .and_then(|_| std::fs::rename(&tmp, path))
        .map_err(FileError::at(format!("cannot write {}", path.display())))
}

/// Creates `dir` (and missing parents) readable by this user only.
pub(crate) fn create_private_dir(dir: &Path) -> Result<(), FileError> {
    use std::os::unix::fs::DirBuilderExt;
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .map_err(FileError::at(format!("cannot create {}", dir.display())))
}

/// Reads the learner address a running learner wrote into `run_dir`.
pub fn read_addr(run_dir: &Path) -> Result<String, FileError> {
    let p: PathBuf = run_dir.join(ADDR_FILE);
    std::fs::read_to_string(&p)
        .map(|s| s.trim().to_owned())
        .map_err(FileError::at(format!("cannot read {}", p.display())))
}

/// The run directory of a starting learner: created, locked, aborted checkpoint saves removed.
pub(crate) struct RunDir {
    /// The run directory.
    pub(crate) path: PathBuf,
    /// Held while this learner serves the run directory (see [`lock_run_dir`]).
    pub(crate) lock: std::fs::File,
    /// Its `checkpoints` directory.
    pub(crate) checkpoints: PathBuf,
    /// The complete checkpoints in it, oldest first.
    pub(crate) candidates: Vec<(u64, PathBuf)>,
}

impl RunDir {
    /// Checks the service settings, then creates (if needed) and locks the run directory of
    /// `opts`, removes checkpoint saves an earlier learner aborted and lists the complete ones.
    pub(crate) fn open(opts: &LearnerOptions) -> Result<Self, StartError> {
        let path = opts.run_dir.clone();
        opts.service.check()?;
        opts.service.check_init_action(opts.space)?;
        create_private_dir(&path)?;
        // Before anything in the run directory is touched: one learner per run directory.
        let lock = lock_run_dir(&path)?;
        let checkpoints = path.join("checkpoints");
        match retention::remove_aborted_saves(&checkpoints) {
            Ok(removed) => {
                for dir in removed {
                    tracing::info!(dir = %dir.display(), "removed a directory left by an aborted checkpoint save");
                }
            }
            Err(e) => tracing::warn!("cannot clean aborted checkpoint saves: {e}"),
        }
        let candidates = if checkpoints.exists() {
            retention::complete_checkpoints(&checkpoints).map_err(ResumeError::from)?
        } else {
            Vec::new()
        };
        Ok(Self {
            path,
            lock,
            checkpoints,
            candidates,
        })
    }

    /// What training starts from: the newest usable checkpoint with `--resume` (and the
    /// warnings about the newer ones skipped), or a fresh state (the actor fitted to
    /// `[service] init_action` when given, else to the DDP schedule with `ddp_init`, except in
    /// the velocity space). Refuses `--resume` without a checkpoint and a fresh run in a
    /// directory that holds one.
    pub(crate) fn training_state(
        &self,
        opts: &LearnerOptions,
        registry_cfg: &RegistryConfig,
    ) -> Result<(TrainingState, Vec<String>, Option<ResumeStatus>), StartError> {
        let device = opts.device.open()?;
        tracing::info!(device = %opts.device, "learner device");
        match (opts.resume, self.candidates.last()) {
            (true, None) => Err(ResumeError::NothingToResume {
                dir: self.checkpoints.clone(),
            }
            .into()),
            (false, Some((_, c))) => Err(ResumeError::RunExists {
                run_dir: self.path.clone(),
                checkpoint: c.clone(),
            }
            .into()),
            (true, Some(_)) => {
                let (ckpt, state, warnings) =
                    newest_usable(&self.checkpoints, &self.candidates, registry_cfg, &device)?;
                let resumed = ResumeStatus {
                    checkpoint: ckpt.display().to_string(),
                    inserts: state.rate.inserts(),
                    updates: state.rate.updates(),
                };
                tracing::info!(
                    run_id = %state.run_id,
                    checkpoint = %resumed.checkpoint,
                    inserts = resumed.inserts,
                    updates = resumed.updates,
                    "resuming run"
                );
                Ok((state, warnings, Some(resumed)))
            }
            (false, None) => {
                let mut td3 = Td3::new(opts.td3.clone(), &device).map_err(StartError::Td3)?;
                match opts.service.start_action(opts.env.action_map, opts.space) {
                    StartAction::Ddp(_) if opts.space == settings::ActionSpace::Velocity => {
                        // The velocity space drives the robot itself: there is no DDP to start
                        // from, and a constant fitted action would only be a fixed command.
                        tracing::info!(
                            "ddp_init skipped: the velocity action space has no DDP schedule; the \
                             actor starts from its random initialization (outputs near 0: about \
                             half the speed cap, straight ahead)"
                        );
                    }
                    StartAction::Ddp(target) => {
                        let report = td3
                            .init_actor_to_action(&target, &FitOptions::default())
                            .map_err(StartError::DdpInit)?;
                        tracing::info!("actor initialized to the DDP schedule ({report:?})");
                    }
                    StartAction::Given(target) => {
                        let report = td3
                            .init_actor_to_action(&target, &FitOptions::default())
                            .map_err(StartError::DdpInit)?;
                        tracing::info!(
                            init_action = ?opts.service.init_action,
                            "actor initialized to [service] init_action ({report:?})"
                        );
                    }
                    StartAction::Random => {}
                }
                let registry =
                    Registry::new(*registry_cfg, opts.worlds.clone()).map_err(StartError::Registry)?;
                let cfg = td3.config().clone();
                let state = TrainingState {
                    td3,
                    run_id: opts.run_id.clone(),
                    rate: RateLimiter::new(&cfg),
                    sampler_rng: seeded_rng(cfg.seed, 4),
                    policy_version: 0,
                    registry,
                    totals: Totals::default(),
                    replay: ReplayBuffer::new(&cfg),
                };
                Ok((state, Vec::new(), None))
            }
        }
    }
}
