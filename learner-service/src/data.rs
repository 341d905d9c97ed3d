//! The data planes on the learner side: the gRPC `Data` service (client-streamed step batches,
//! server-streamed policy versions) and the shared-memory intake thread. Both hand every record
//! to [`Shared::ingest`], which validates it before anything reaches the buffer.

use std::cell::RefCell;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender};
use std::sync::Arc;
use std::time::Duration;

use proto::grpc::{for_each_step, DecodeScratch};
use proto::pb::{self, data_server::Data};
use proto::plane::LeaseHeader;
use proto::shm::{ShmConfig, ShmError, ShmStepSource};
use proto::validate::Refusal;
use proto::StepView;
use tokio_stream::Stream;
use tonic::{Request, Response, Status, Streaming};

use crate::ingest::{Plane, Stored};
use crate::shared::Shared;

thread_local! {
    static SCRATCH: RefCell<DecodeScratch> = RefCell::new(DecodeScratch::default());
}

/// Validates and stores one batch; returns its acknowledgement (records accepted, recognised
/// as duplicates, refused, and the first refusal's reason).
fn ingest_batch(shared: &Shared, batch: &pb::StepBatch) -> pb::Ack {
    let n = batch.steps.len() as u64;
    let refused_whole = |why: &Refusal| pb::Ack {
        refused: n,
        reason: why.to_string(),
        ..pb::Ack::default()
    };
    let run = batch.run.clone().unwrap_or_default();
    if let Err(why) = shared.validator.check_run(&run.run_id, run.incarnation) {
        let _actor =
            tracing::info_span!("actor", actor_id = batch.actor_id, lease = batch.lease_id).entered();
        shared.refuse(&why, n);
        return refused_whole(&why);
    }
    // Who sends decides whether anything of the batch is looked at: a batch naming another
    // actor (without its credential) is refused whole, before a record is decoded.
    let secret = match shared.authenticate(batch.actor_id, &batch.actor_secret) {
        Ok(()) => batch.actor_secret[..]
            .try_into()
            .expect("a matching secret has the credential's length"),
        Err(why) => {
            let _actor =
                tracing::info_span!("actor", actor_id = batch.actor_id, lease = batch.lease_id).entered();
            shared.refuse(&why, n);
            return refused_whole(&why);
        }
    };
    let header = LeaseHeader {
        incarnation: run.incarnation,
        actor_id: batch.actor_id,
        lease_id: batch.lease_id,
        secret,
    };
    let mut ack = pb::Ack::default();
    SCRATCH.with_borrow_mut(|scratch| {
        for_each_step(batch, scratch, |decoded| {
            let result = match decoded {
                Ok(view) => shared.ingest(Plane::Grpc, &header, &view),
                Err(ragged) => {
                    // Like every other malformed step, it ends its lease.
                    let why = Refusal::from(ragged);
                    let _actor =
                        tracing::info_span!("actor", actor_id = header.actor_id, lease = header.lease_id)
                            .entered();
                    shared.break_lease(&header, &why);
                    shared.refuse(&why, 1);
                    Err(why)
                }
            };
            match result {
                Ok(Stored::Inserted) => ack.accepted += 1,
                Ok(Stored::Duplicate) => ack.duplicates += 1,
                Err(why) => {
                    if ack.refused == 0 {
                        ack.reason = why.to_string();
                    }
                    ack.refused += 1;
                }
            }
        })
    });
    ack
}

/// The `adp.v1.Data` service's `PushSteps` (`WatchPolicy` is answered by
/// [`crate::policy_streams::DataRoutes`] before a request reaches this service).
pub struct DataService {
    pub(super) shared: Arc<Shared>,
}

type PolicyStream = Pin<Box<dyn Stream<Item = Result<pb::PolicySnapshot, Status>> + Send>>;

#[tonic::async_trait]
impl Data for DataService {
    async fn push_steps(
        &self,
        request: Request<Streaming<pb::StepBatch>>,
    ) -> Result<Response<pb::Ack>, Status> {
        let mut stream = request.into_inner();
        let mut ack = pb::Ack::default();
        while let Some(batch) = stream.message().await? {
            let shared = self.shared.clone();
            let b = tokio::task::spawn_blocking(move || ingest_batch(&shared, &batch))
                .await
                .map_err(|e| Status::internal(format!("step intake failed: {e}")))?;
            ack.accepted += b.accepted;
            ack.duplicates += b.duplicates;
            if b.refused > 0 && ack.refused == 0 {
                ack.reason = b.reason;
            }
            ack.refused += b.refused;
        }
        Ok(Response::new(ack))
    }

    type WatchPolicyStream = PolicyStream;

    async fn watch_policy(
        &self,
        _request: Request<pb::PolicyRequest>,
    ) -> Result<Response<PolicyStream>, Status> {
        Err(Status::internal(
            "WatchPolicy is served by the learner's policy streams, not here",
        ))
    }
}

/// Drains the shared-memory step service into [`Shared::ingest`] until `stop` is set.
///
/// Opens the service first and says whether that worked on `opened`; then waits for the shared
/// state on `shared` (the learner builds it once it knows which plane actors get).
pub fn shm_intake(
    cfg: ShmConfig,
    opened: SyncSender<Result<(), ShmError>>,
    shared: Receiver<Arc<Shared>>,
    stop: Arc<AtomicBool>,
) {
    let mut source = match ShmStepSource::open(&cfg) {
        Ok(s) => {
            let _ = opened.send(Ok(()));
            s
        }
        Err(e) => {
            let _ = opened.send(Err(e));
            return;
        }
    };
    let Ok(shared) = shared.recv() else {
        return;
    };
    // The slots live in memory the actor can still write: copy each record before validating
    // it, so what is checked is what is stored.
    let (mut obs, mut action, mut final_obs) = (Vec::new(), Vec::new(), Vec::new());
    while !stop.load(Ordering::Acquire) {
        let drained = source.drain(256, |header, view| {
            obs.clear();
            obs.extend_from_slice(view.obs);
            action.clear();
            action.extend_from_slice(view.action);
            final_obs.clear();
            final_obs.extend_from_slice(view.final_obs);
            let copy = StepView {
                obs: &obs,
                action: &action,
                final_obs: &final_obs,
                ..*view
            };
            let _ = shared.ingest(Plane::Shm, header, &copy);
        });
        match drained {
            Ok(0) => std::thread::sleep(Duration::from_millis(1)),
            Ok(_) => {}
            Err(e) => {
                tracing::error!("shared-memory receive failed: {e}");
                std::thread::sleep(Duration::from_millis(100));
            }
        }
    }
}
