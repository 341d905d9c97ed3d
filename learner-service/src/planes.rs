//! The shared-memory data plane of a starting learner: its step service, opened on the intake
//! thread before actors are told which plane to use.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::thread::JoinHandle;

use proto::shm::ShmConfig;

use crate::config::ServiceConfig;
use crate::data;
use crate::error::{FileError, StartError};
use crate::shared::Shared;

/// The shared-memory data plane (when configured and it opened) and its intake thread.
pub(crate) struct DataPlanes {
    /// The step and policy services actors use, when shared memory is offered.
    pub(crate) shm: Option<ShmConfig>,
    /// Why shared memory is not offered although configured.
    pub(crate) shm_unavailable: Option<String>,
    /// The intake thread, when shared memory is offered.
    pub(crate) intake: Option<JoinHandle<()>>,
    /// Tells the intake thread to stop.
    pub(crate) intake_stop: Arc<AtomicBool>,
    /// Hands the intake thread the shared state once it exists.
    pub(crate) shared_tx: std::sync::mpsc::SyncSender<Arc<Shared>>,
}

impl DataPlanes {
    /// Opens the shared-memory step service of run `run_id`'s `incarnation` (when
    /// `[service] shared_memory`) on its intake thread.
    ///
    /// The intake opens its step service before actors are told which plane to use: if that
    /// fails, the run offers gRPC only (the reason is logged and shown in status.json) rather
    /// than sending actors to a plane nobody drains.
    pub(crate) fn start(svc: &ServiceConfig, run_id: &str, incarnation: u64) -> Result<Self, StartError> {
        let shm = svc.shared_memory.then(|| ShmConfig {
            service_prefix: format!("adp/{run_id}/{incarnation:016x}"),
            max_actors: svc.shm_max_actors as usize,
            ..ShmConfig::default()
        });
        let intake_stop = Arc::new(AtomicBool::new(false));
        let (shared_tx, shared_rx) = std::sync::mpsc::sync_channel::<Arc<Shared>>(1);
        let (shm, shm_unavailable, intake) = match shm {
            Some(cfg) => {
                let (opened_tx, opened_rx) = std::sync::mpsc::sync_channel(1);
                let (c, stop) = (cfg.clone(), intake_stop.clone());
                let handle = std::thread::Builder::new()
                    .name("adp-shm-intake".into())
                    .spawn(move || data::shm_intake(c, opened_tx, shared_rx, stop))
                    .map_err(FileError::at("cannot start the shared-memory intake thread"))?;
                match opened_rx.recv() {
                    Ok(Ok(())) => (Some(cfg), None, Some(handle)),
                    Ok(Err(why)) => {
                        tracing::warn!("shared-memory data plane unavailable ({why}); actors use gRPC");
                        let _ = handle.join();
                        (None, Some(why.to_string()), None)
                    }
                    Err(_) => {
                        let _ = handle.join();
                        (None, Some("the intake thread ended".to_owned()), None)
                    }
                }
            }
            None => (None, None, None),
        };
        Ok(Self {
            shm,
            shm_unavailable,
            intake,
            intake_stop,
            shared_tx,
        })
    }
}
