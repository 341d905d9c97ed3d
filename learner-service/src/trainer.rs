//! The training thread: TD3 updates under the rate limiter, policy publishing at each new
//! cycle, TensorBoard and `status.json`, periodic and final checkpoints, and the final export.
//!
//! It owns the [`Td3`] state; everything else it reaches through [`Shared`].

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use proto::pb;
use proto::shm::{ShmConfig, ShmPolicyPublisher};
use rand_pcg::Pcg64Mcg;
use settings::ActionSpace;
use tokio::sync::watch;

use crate::error::TrainError;
use crate::run_dir::create_private_dir;
use crate::shared::{Rates, Shared};
use crate::status::write_status;
use crate::totals::Totals;
use crate::ServiceConfig;
use learner::batch::Batch;
use learner::checkpoint::{self, RunState};
use learner::exploration::ExplorationSchedule;
use learner::export::export_checkpoint;
use learner::retention;
use learner::td3::Td3;
use learner::tensorboard::EventWriter;

/// What the training thread needs besides the shared state.
pub struct Trainer {
    pub(super) shared: Arc<Shared>,
    pub(super) td3: Td3,
    pub(super) sampler_rng: Pcg64Mcg,
    pub(super) run_dir: PathBuf,
    pub(super) service: ServiceConfig,
    pub(super) space: ActionSpace,
    pub(super) policy_tx: watch::Sender<Arc<pb::PolicySnapshot>>,
    pub(super) shm: Option<ShmConfig>,
    pub(super) tensorboard: EventWriter,
    /// The actors' environment settings (recorded in every checkpoint for the export card).
    pub(super) environment: serde_json::Value,
}

/// How the training thread ended.
#[derive(Debug, Clone)]
pub struct TrainSummary {
    /// Agent steps stored in total.
    pub inserts: u64,
    /// Gradient updates in total.
    pub updates: u64,
    /// The final checkpoint.
    pub checkpoint: PathBuf,
    /// The export directory, when the export succeeded.
    pub export: Option<PathBuf>,
    /// Whether the budget was reached (false after a stop request).
    pub completed: bool,
}

/// Rates between two status points.
struct Meter {
    at: Instant,
    inserts: u64,
    updates: u64,
}

impl Trainer {
    /// Runs until the budget is stored and trained on, or a stop is requested; then writes the
    /// final checkpoint and export.
    pub fn run(mut self) -> Result<TrainSummary, TrainError> {
        let mut shm_pub = self.open_shm_publisher();
        let exploration = ExplorationSchedule::new(self.td3.config(), self.shared.budget);
        let cfg = self.td3.config().clone();
        let mut batch = Batch::new(cfg.obs_dim, cfg.act_dim);
        let mut published: Option<u64> = None;
        let shm_silent = shm_policy_silent();
        // A failed shared-memory publish: (version, sigma, when), retried until it works.
        let mut shm_retry: Option<(u64, f64, Instant)> = None;
        let mut last_checkpoint = Instant::now();
        let status_every = Duration::from_secs_f64(self.service.status_every_s);
        let mut last_status = Instant::now() - status_every;
        let start = {
            let core = self.shared.lock();
            (core.rate.inserts(), core.rate.updates())
        };
        let mut meter = Meter {
            at: Instant::now(),
            inserts: start.0,
            updates: start.1,
        };
        let completed;
        loop {
            // Decide under the lock; act outside it.
            let mut core = self.shared.lock();
            let cycle = core.registry.cycle();
            let publish = published.is_none_or(|v| cycle > v);
            let can_update = core.rate.updates_allowed() > 0 && core.replay.ready_len() > 0 && !core.abort;
            let owed = core.rate.target_updates().floor() as u64 > core.rate.updates();
            // Past the budget, open leases still deliver their episodes (their actors wait for
            // them to finish before they leave): train on them too, then stop.
            let done = core.abort
                || (core.stopping
                    && !owed
                    && core.rate.inserts() >= self.shared.budget
                    && core.open_leases() == 0);
            if done {
                completed = !core.abort;
                core.closed = true;
                break;
            }
            if publish {
                let version = cycle.max(core.policy_version);
                let sigma = exploration.sigma(core.rate.inserts());
                // Steps made with this version may arrive as soon as either plane carries it:
                // the learner must already accept it.
                core.policy_version = version;
                drop(core);
                shm_retry = self.publish(version, sigma, shm_pub.as_mut().filter(|_| !shm_silent));
                published = Some(version);
                continue;
            }
            if let (Some((version, sigma, at)), Some(p)) = (shm_retry, shm_pub.as_mut()) {
                if at.elapsed() >= Duration::from_millis(100) {
                    drop(core);
                    // The networks have not changed since the publish: the actors of this cycle
                    // need exactly that version. (A run that trains on moves to the next cycle
                    // with a fresh publish.)
                    let weights = self.snapshot_weights_of(version);
                    shm_retry = match weights.map(|w| p.publish(version, sigma, &w)) {
                        Some(Ok(())) => {
                            tracing::info!(version, "shared-memory policy published on retry");
                            None
                        }
                        _ => Some((version, sigma, Instant::now())),
                    };
                    continue;
                }
            }
            if can_update {
                let sampled = core
                    .replay
                    .sample(cfg.batch_size, &mut self.sampler_rng, &mut batch);
                drop(core);
                sampled.map_err(TrainError::Sample)?;
                self.update(&batch)?;
            } else {
                let _ = self
                    .shared
                    .wake
                    .wait_timeout(core, Duration::from_millis(20))
                    .expect("learner state lock poisoned");
            }
            if last_status.elapsed() >= status_every {
                last_status = Instant::now();
                self.report(&mut meter, &exploration);
            }
            if last_checkpoint.elapsed().as_secs_f64() >= self.service.checkpoint_every_s {
                last_checkpoint = Instant::now();
                if let Err(e) = self.checkpoint() {
                    tracing::error!("periodic checkpoint failed (the run goes on): {e}");
                }
            }
        }
        self.finish(&mut meter, &exploration, completed)
    }

    /// The shared-memory policy publisher of the run, or `None` (gRPC only) when it has none
    /// or it cannot open (noted in the status).
    fn open_shm_publisher(&self) -> Option<ShmPolicyPublisher> {
        match ShmPolicyPublisher::open(self.shm.as_ref()?) {
            Ok(p) => Some(p),
            Err(e) => {
                tracing::warn!("cannot publish policies over shared memory ({e}); gRPC only");
                *self.shared.shm_unavailable.lock().expect("shm note lock") =
                    Some(format!("policy publisher: {e}"));
                None
            }
        }
    }

    /// Publishes the current actor as policy `version` with exploration `sigma` on gRPC and on
    /// `shm` when given; returns the retry of a failed shared-memory publish.
    fn publish(
        &mut self,
        version: u64,
        sigma: f64,
        shm: Option<&mut ShmPolicyPublisher>,
    ) -> Option<(u64, f64, Instant)> {
        let (_, weights) = self.td3.policy().flat_weights();
        let mut retry = None;
        if let Some(p) = shm {
            if let Err(e) = p.publish(version, sigma, &weights) {
                tracing::warn!(version, "shared-memory policy publish failed ({e}); retrying");
                retry = Some((version, sigma, Instant::now()));
            }
        }
        let snapshot = pb::PolicySnapshot {
            version,
            exploration_sigma: sigma,
            weights: proto::floats::encode(&weights).into(),
        };
        self.policy_tx.send_replace(Arc::new(snapshot));
        self.shared.wake.notify_all();
        retry
    }

    /// One TD3 update on `batch`, counted; every tenth one's statistics go to TensorBoard.
    fn update(&mut self, batch: &Batch) -> Result<(), TrainError> {
        let stats = self.td3.update(batch).map_err(TrainError::Update)?;
        let (inserts, updates) = {
            let mut core = self.shared.lock();
            core.rate.record_updates(1);
            (core.rate.inserts(), core.rate.updates())
        };
        self.shared.wake.notify_all();
        if updates.is_multiple_of(10) {
            let _ = self.tensorboard.update_stats(inserts, &stats);
        }
        Ok(())
    }

    /// The end of a run: the final checkpoint and export, the last status.
    fn finish(
        &mut self,
        meter: &mut Meter,
        exploration: &ExplorationSchedule,
        completed: bool,
    ) -> Result<TrainSummary, TrainError> {
        let checkpoint = self.final_checkpoint()?;
        let (inserts, updates) = {
            let core = self.shared.lock();
            (core.rate.inserts(), core.rate.updates())
        };
        let export_dir = self.run_dir.join("export");
        let export = match export_checkpoint(&checkpoint, &export_dir, self.space) {
            Ok(_) => Some(export_dir),
            Err(e) => {
                tracing::error!("export failed: {e}");
                None
            }
        };
        // The last status says so: the final checkpoint (and export) are on disk.
        self.shared.finished.store(true, Ordering::Release);
        self.report(meter, exploration);
        Ok(TrainSummary {
            inserts,
            updates,
            checkpoint,
            export,
            completed,
        })
    }

    /// The weights of the published policy `version` (as sent over gRPC), if it is the newest.
    fn snapshot_weights_of(&self, version: u64) -> Option<Vec<f32>> {
        let snapshot = self.policy_tx.borrow().clone();
        let mut weights = Vec::new();
        (snapshot.version == version)
            .then(|| proto::floats::decode_into("weights", &snapshot.weights, &mut weights).ok())
            .flatten()
            .map(|()| weights)
    }

    /// Writes `status.json` and the service scalars to TensorBoard.
    fn report(&mut self, meter: &mut Meter, exploration: &ExplorationSchedule) {
        let mut core = self.shared.lock();
        let dt = meter.at.elapsed().as_secs_f64().max(1e-9);
        let (inserts, updates) = (core.rate.inserts(), core.rate.updates());
        let lag = if core.lag.1 > 0 {
            core.lag.0 as f64 / core.lag.1 as f64
        } else {
            0.0
        };
        core.lag = (0, 0);
        let status = self.shared.status(
            &core,
            Rates {
                inserts_per_s: (inserts - meter.inserts) as f64 / dt,
                updates_per_s: (updates - meter.updates) as f64 / dt,
                policy_lag: lag,
                exploration_sigma: exploration.sigma(inserts),
            },
        );
        drop(core);
        *meter = Meter {
            at: Instant::now(),
            inserts,
            updates,
        };
        if let Err(e) = write_status(&self.run_dir, &status) {
            tracing::error!("{e}");
        }
        let _ = self.tensorboard.scalars(inserts, &status.scalars());
        let _ = self.tensorboard.flush();
    }

    /// The last checkpoint of the run: retried (up to [`FINAL_CHECKPOINT_TRIES`] times, a
    /// second apart) when it cannot be written for a reason that may pass (the open-file limit
    /// reached, a full disk being cleaned up), each failure reported. A failed attempt leaves
    /// only a `.tmp-` directory, which never counts as a checkpoint, so the previous complete
    /// checkpoint stays the one a resume uses.
    fn final_checkpoint(&mut self) -> Result<PathBuf, TrainError> {
        let mut attempt = 1;
        loop {
            match self.checkpoint() {
                Ok(dir) => return Ok(dir),
                Err(e) if attempt < FINAL_CHECKPOINT_TRIES => {
                    tracing::error!(attempt, "final checkpoint failed ({e}); retrying in 1 s");
                    attempt += 1;
                    std::thread::sleep(Duration::from_secs(1));
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// Writes a checkpoint of the whole run (networks, optimizers, RNGs, rate limiter, registry,
    /// counters, and the replay buffer when configured) and prunes old ones.
    ///
    /// The core lock is held only to copy the shared state (counters, registry snapshot, the
    /// replay buffer's snapshot bytes); serializing the networks, hashing and fsyncing happen
    /// outside it, so heartbeats, leases and ingest go on during a slow write. The networks
    /// belong to this thread, so nothing changes them meanwhile.
    fn checkpoint(&mut self) -> Result<PathBuf, TrainError> {
        let root = self.run_dir.join("checkpoints");
        let (dir, run, replay) = {
            let core = self.shared.lock();
            let name = format!("ckpt-{:012}-{:012}", core.rate.inserts(), core.rate.updates());
            let dir = root.join(&name);
            if dir.join(checkpoint::MANIFEST).exists() {
                return Ok(dir);
            }
            let run = RunState {
                run_id: self.shared.validator.run_id.clone(),
                rate: core.rate.clone(),
                sampler_rng: self.sampler_rng.clone(),
                policy_version: core.policy_version,
                extra: serde_json::json!({
                    "registry": core.registry.snapshot(),
                    "totals": Totals {
                        refusals: self.shared.refusals.by_name(),
                        ..core.totals.clone()
                    },
                }),
                environment: self.environment.clone(),
            };
            let replay = if self.service.checkpoint_replay {
                let mut bytes = Vec::new();
                core.replay
                    .write_snapshot(&mut bytes)
                    .map_err(|source| TrainError::ReplayCopy {
                        dir: dir.clone(),
                        source,
                    })?;
                Some(bytes)
            } else {
                None
            };
            (dir, run, replay)
        };
        if let Some(ms) = slow_checkpoint_ms() {
            // Tests: stand in for a slow shared filesystem (outside the lock, like the write).
            std::thread::sleep(Duration::from_millis(ms));
        }
        create_private_dir(&root)?;
        let saved = match &replay {
            Some(bytes) => checkpoint::save_with_replay_snapshot(&dir, &self.td3, &run, bytes),
            None => checkpoint::save(&dir, &self.td3, &run),
        };
        drop(replay);
        saved.map_err(|source| TrainError::Save {
            dir: dir.clone(),
            source,
        })?;
        tracing::info!(dir = %dir.display(), "checkpoint written");
        if let Err(e) = retention::prune(&root, self.service.keep_checkpoints.max(1), &[]) {
            tracing::warn!("pruning old checkpoints: {e}");
        }
        Ok(dir)
    }
}

/// Attempts at the final checkpoint before the learner gives up (see
/// `Trainer::final_checkpoint`).
const FINAL_CHECKPOINT_TRIES: u32 = 5;

/// Test hook: with `ADP_TEST_SHM_POLICY_SILENT=1` the shared-memory policy publisher is opened
/// but never publishes, to stand in for a shared-memory policy that never reaches the actors.
fn shm_policy_silent() -> bool {
    std::env::var("ADP_TEST_SHM_POLICY_SILENT").as_deref() == Ok("1")
}

/// Test hook: `ADP_TEST_SLOW_CHECKPOINT_MS` delays every checkpoint write by that long, to
/// stand in for a slow shared filesystem.
fn slow_checkpoint_ms() -> Option<u64> {
    std::env::var("ADP_TEST_SLOW_CHECKPOINT_MS")
        .ok()
        .and_then(|v| v.parse().ok())
}
