//! The gRPC side: connecting to the learner (token, optional TLS), the actor-side gRPC data
//! plane ([`GrpcStepSink`], [`GrpcPolicySource`]) and decoding received step batches
//! ([`for_each_step`]).
//!
//! The actor loop is synchronous; these types bridge to a tokio runtime whose [`Handle`] they
//! are given (the runtime must have at least one worker thread running while they are used).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use thiserror::Error;
use tokio::runtime::Handle;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio_stream::wrappers::ReceiverStream;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, Endpoint};

use crate::auth::{AuthError, ClientAuth, TlsFiles};
use crate::floats::{self, RaggedBytes};
use crate::pb;
use crate::plane::{ActorSecret, LeaseHeader, PlaneError, PolicySource, PolicyUpdate, SinkTally, StepSink};
use crate::validate::StepView;

/// Largest gRPC message either side accepts (a policy snapshot is about 2.5 MB; a step batch of
/// 64 records about 190 KB).
pub const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// Largest data-plane request the learner accepts: a `StepBatch` of [`BATCH_RECORDS`] records is
/// about 190 KB (twice that if every record is truncated and carries `final_obs`).
pub const MAX_REQUEST_BYTES: usize = 1 << 20;

/// Largest control-plane request the learner accepts (registrations, heartbeats, reports are
/// a few hundred bytes).
pub const MAX_CONTROL_REQUEST_BYTES: usize = 64 << 10;

/// Step records per `StepBatch` message.
pub const BATCH_RECORDS: usize = 64;

/// The control-plane client with the token interceptor.
pub type ControlClient = pb::control_client::ControlClient<InterceptedService<Channel, ClientAuth>>;
/// The data-plane client with the token interceptor.
pub type DataClient = pb::data_client::DataClient<InterceptedService<Channel, ClientAuth>>;

/// Where and how to reach the learner.
#[derive(Debug, Clone, Default)]
pub struct LearnerAddress {
    /// `host:port`, or `unix:PATH` for the learner's Unix socket on this host (what sandboxed
    /// actors without a network use).
    pub addr: String,
    /// The run's token (sent on every call).
    pub token: Option<String>,
    /// TLS; plain HTTP/2 when `None`.
    pub tls: Option<TlsFiles>,
}

/// Why the learner could not be reached.
#[derive(Debug, Error)]
pub enum ConnectError {
    /// The address is not `host:port`.
    #[error("learner address `{addr}`: {reason}")]
    Address {
        /// The address.
        addr: String,
        /// What is wrong.
        reason: String,
    },
    /// TLS files could not be used.
    #[error(transparent)]
    Tls(#[from] AuthError),
    /// The connection failed.
    #[error("cannot connect to the learner at {addr}: {source}")]
    Transport {
        /// The address.
        addr: String,
        /// tonic's error.
        source: tonic::transport::Error,
    },
}

impl LearnerAddress {
    /// Opens one HTTP/2 channel (shared by the control and data clients).
    pub async fn connect(&self) -> Result<(ControlClient, DataClient), ConnectError> {
        let channel = match self.addr.strip_prefix("unix:") {
            Some(path) => self.connect_unix(path).await?,
            None => self.connect_tcp().await?,
        };
        let auth = ClientAuth::new(self.token.as_deref());
        let control = pb::control_client::ControlClient::with_interceptor(channel.clone(), auth.clone())
            .max_decoding_message_size(MAX_MESSAGE_BYTES);
        let data = pb::data_client::DataClient::with_interceptor(channel, auth)
            .max_decoding_message_size(MAX_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES);
        Ok((control, data))
    }

    /// A channel over the Unix socket at `path` (plain HTTP/2: the socket never leaves the host;
    /// the token is still sent and checked).
    async fn connect_unix(&self, path: &str) -> Result<Channel, ConnectError> {
        if self.tls.is_some() {
            return Err(ConnectError::Address {
                addr: self.addr.clone(),
                reason: "TLS is for TCP addresses; a Unix socket stays on this host".into(),
            });
        }
        let path = std::path::PathBuf::from(path);
        // The URI is required by the HTTP/2 layer but not used to connect.
        let ep = Endpoint::from_static("http://localhost")
            .connect_timeout(Duration::from_secs(5))
            .http2_keep_alive_interval(Duration::from_secs(10))
            .keep_alive_timeout(Duration::from_secs(20));
        ep.connect_with_connector(tower::service_fn(move |_: tonic::transport::Uri| {
            let path = path.clone();
            async move {
                let stream = tokio::net::UnixStream::connect(path).await?;
                Ok::<_, std::io::Error>(hyper_util::rt::TokioIo::new(stream))
            }
        }))
        .await
        .map_err(|source| ConnectError::Transport {
            addr: self.addr.clone(),
            source,
        })
    }

    async fn connect_tcp(&self) -> Result<Channel, ConnectError> {
        let host = self
            .addr
            .rsplit_once(':')
            .map(|(h, _)| h.trim_matches(['[', ']']))
            .filter(|h| !h.is_empty())
            .ok_or_else(|| ConnectError::Address {
                addr: self.addr.clone(),
                reason: "expected host:port".into(),
            })?;
        let scheme = if self.tls.is_some() { "https" } else { "http" };
        let mut ep = Endpoint::from_shared(format!("{scheme}://{}", self.addr))
            .map_err(|e| ConnectError::Address {
                addr: self.addr.clone(),
                reason: e.to_string(),
            })?
            .connect_timeout(Duration::from_secs(5))
            .tcp_nodelay(true)
            // A learner that stops answering (a partition, a dead node) is noticed within 30 s;
            // the step sink then resends what was not acknowledged on a new connection. (An
            // actor queued behind a flood in a loaded learner's backlog waits longer than 15 s.)
            .http2_keep_alive_interval(Duration::from_secs(10))
            .keep_alive_timeout(Duration::from_secs(20));
        if let Some(tls) = &self.tls {
            ep = ep
                .tls_config(tls.client_config(host)?)
                .map_err(|source| ConnectError::Transport {
                    addr: self.addr.clone(),
                    source,
                })?;
        }
        ep.connect().await.map_err(|source| ConnectError::Transport {
            addr: self.addr.clone(),
            source,
        })
    }
}

/// Reusable buffers for decoding step records. Not shared between threads.
#[derive(Debug, Default)]
pub struct DecodeScratch {
    obs: Vec<f32>,
    action: Vec<f32>,
    final_obs: Vec<f32>,
}

/// Decodes every record of `batch` into `scratch` and hands it to `f` as a [`StepView`]; a
/// record whose bytes are ragged is handed to `f` as the error instead. No allocation once the
/// scratch buffers have grown.
pub fn for_each_step(
    batch: &pb::StepBatch,
    scratch: &mut DecodeScratch,
    mut f: impl FnMut(Result<StepView<'_>, RaggedBytes>),
) {
    for rec in &batch.steps {
        let decoded = floats::decode_into("obs", &rec.obs, &mut scratch.obs)
            .and_then(|_| floats::decode_into("action", &rec.action, &mut scratch.action))
            .and_then(|_| floats::decode_into("final_obs", &rec.final_obs, &mut scratch.final_obs));
        f(decoded.map(|_| StepView {
            episode_id: rec.episode_id,
            step_index: rec.step_index,
            policy_version: rec.policy_version,
            obs: &scratch.obs,
            action: &scratch.action,
            reward: rec.reward,
            terminal: rec.terminal,
            truncated: rec.truncated,
            final_obs: &scratch.final_obs,
        }));
    }
}

/// Encodes one step as a record.
pub fn encode_step(step: &StepView<'_>) -> pb::StepRecord {
    pb::StepRecord {
        episode_id: step.episode_id,
        step_index: step.step_index,
        policy_version: step.policy_version,
        obs: floats::encode(step.obs).into(),
        action: floats::encode(step.action).into(),
        reward: step.reward,
        terminal: step.terminal,
        truncated: step.truncated,
        final_obs: floats::encode(step.final_obs).into(),
    }
}

/// One open `PushSteps` client stream.
struct OpenStream {
    tx: mpsc::Sender<pb::StepBatch>,
    call: JoinHandle<Result<tonic::Response<pb::Ack>, tonic::Status>>,
}

/// Why a stream ended without an acknowledgement, and whether resending may still work.
struct Broken {
    detail: String,
    /// The learner may take the records on a new stream (a transport failure); `false` when it
    /// turned the stream away for good (bad credentials, a malformed message).
    resend: bool,
}

impl Broken {
    fn of(call: Result<Result<tonic::Response<pb::Ack>, tonic::Status>, tokio::task::JoinError>) -> Self {
        match call {
            Ok(Err(status)) => Broken {
                detail: format!("{:?}: {}", status.code(), status.message()),
                resend: !matches!(
                    status.code(),
                    tonic::Code::InvalidArgument
                        | tonic::Code::Unauthenticated
                        | tonic::Code::PermissionDenied
                        | tonic::Code::NotFound
                        | tonic::Code::FailedPrecondition
                        | tonic::Code::Unimplemented
                        | tonic::Code::OutOfRange
                ),
            },
            Ok(Ok(_)) => Broken {
                detail: "the learner closed the step stream early".into(),
                resend: true,
            },
            Err(e) => Broken {
                detail: e.to_string(),
                resend: false,
            },
        }
    }
}

/// First wait before a broken stream is resent; it doubles up to [`RESEND_WAIT_MAX`].
const RESEND_WAIT: Duration = Duration::from_millis(200);
/// Longest wait between two resends.
const RESEND_WAIT_MAX: Duration = Duration::from_secs(5);

/// The actor side of the gRPC data plane: records are batched ([`BATCH_RECORDS`] per message)
/// onto one client stream per flush interval; [`StepSink::flush`] closes the stream and waits
/// for the learner's acknowledgement, so after it returns every record was received and
/// accounted for (accepted, recognised as a duplicate, or refused). `Send`, not `Sync`.
///
/// Every batch is kept until a stream carrying it is acknowledged. When a stream breaks (the
/// connection dropped, the learner did not answer its keep-alives), all kept batches are sent
/// again on a new stream, with back-off, for up to the sink's patience; the learner stores
/// each record once and acknowledges the ones it had already stored as duplicates. Past the
/// patience the records are given up ([`SinkTally::unacknowledged`]) and the error says how
/// many.
pub struct GrpcStepSink {
    handle: Handle,
    client: DataClient,
    run: pb::RunRef,
    batch: pb::StepBatch,
    stream: Option<OpenStream>,
    /// Batches sent since the last acknowledgement (cheap clones: the record bytes are shared).
    unacked: Vec<pb::StepBatch>,
    /// How long to go on resending after a stream broke.
    patience: Duration,
    tally: SinkTally,
}

fn disconnected(detail: impl ToString) -> PlaneError {
    PlaneError::Disconnected {
        plane: "grpc",
        detail: detail.to_string(),
    }
}

impl GrpcStepSink {
    /// A sink for run `run_id` / `incarnation` over `client`, driving its calls on `handle`;
    /// it resends after a broken stream for up to `patience`.
    pub fn new(
        handle: Handle,
        client: DataClient,
        run_id: &str,
        incarnation: u64,
        patience: Duration,
    ) -> Self {
        Self {
            handle,
            client,
            run: pb::RunRef {
                run_id: run_id.to_owned(),
                incarnation,
            },
            batch: pb::StepBatch::default(),
            stream: None,
            unacked: Vec::new(),
            patience,
            tally: SinkTally::default(),
        }
    }

    fn open(&self) -> OpenStream {
        let (tx, rx) = mpsc::channel(4);
        let mut client = self.client.clone();
        let call = self
            .handle
            .spawn(async move { client.push_steps(ReceiverStream::new(rx)).await });
        OpenStream { tx, call }
    }

    /// Sends `batch` on the open stream (opened if none); `Err` when the stream ended early.
    fn send_on_stream(&mut self, batch: pb::StepBatch) -> Result<(), Broken> {
        let stream = match &mut self.stream {
            Some(s) => s,
            None => self.stream.insert(self.open()),
        };
        if stream.tx.blocking_send(batch).is_ok() {
            return Ok(());
        }
        // The call ended early: its status says why.
        let s = self.stream.take().expect("stream is open");
        Err(Broken::of(self.handle.block_on(s.call)))
    }

    fn push_batch(&mut self) -> Result<(), PlaneError> {
        if self.batch.steps.is_empty() {
            return Ok(());
        }
        let batch = std::mem::take(&mut self.batch);
        self.unacked.push(batch.clone());
        match self.send_on_stream(batch) {
            Ok(()) => Ok(()),
            Err(broken) => self.resend(broken),
        }
    }

    fn unacked_records(&self) -> u64 {
        self.unacked.iter().map(|b| b.steps.len() as u64).sum()
    }

    /// After `broken`, sends every unacknowledged batch again on new streams until one takes
    /// them all, or gives them up (with the reason) once resending is hopeless or the patience
    /// is spent.
    fn resend(&mut self, mut broken: Broken) -> Result<(), PlaneError> {
        let start = std::time::Instant::now();
        let mut wait = RESEND_WAIT;
        loop {
            if !broken.resend || start.elapsed() + wait > self.patience {
                let lost = self.unacked_records();
                self.tally.unacknowledged += lost;
                self.unacked.clear();
                self.stream = None;
                return Err(disconnected(format!(
                    "{}; gave up {lost} unacknowledged step records after {:.1} s",
                    broken.detail,
                    start.elapsed().as_secs_f64()
                )));
            }
            std::thread::sleep(wait);
            wait = (wait * 2).min(RESEND_WAIT_MAX);
            self.tally.resends += 1;
            let batches = self.unacked.clone();
            match batches.into_iter().try_for_each(|b| self.send_on_stream(b)) {
                Ok(()) => return Ok(()),
                Err(b) => broken = b,
            }
        }
    }
}

impl StepSink for GrpcStepSink {
    fn send(&mut self, header: &LeaseHeader, step: &StepView<'_>) -> Result<(), PlaneError> {
        let same = self.batch.actor_id == header.actor_id
            && self.batch.lease_id == header.lease_id
            && self.batch.actor_secret[..] == header.secret[..]
            && self.run.incarnation == header.incarnation;
        if !same || self.batch.steps.len() >= BATCH_RECORDS {
            self.push_batch()?;
        }
        if self.batch.steps.is_empty() {
            self.run.incarnation = header.incarnation;
            self.batch.run = Some(self.run.clone());
            self.batch.actor_id = header.actor_id;
            self.batch.lease_id = header.lease_id;
            self.batch.actor_secret = crate::Bytes::copy_from_slice(&header.secret);
        }
        self.batch.steps.push(encode_step(step));
        self.tally.sent += 1;
        Ok(())
    }

    fn flush(&mut self) -> Result<(), PlaneError> {
        self.push_batch()?;
        loop {
            let Some(OpenStream { tx, call }) = self.stream.take() else {
                return Ok(());
            };
            drop(tx);
            let ack = match self.handle.block_on(call) {
                Ok(Ok(r)) => r.into_inner(),
                failed => {
                    // The stream broke before its acknowledgement: send everything again, then
                    // close that stream in the next round.
                    self.resend(Broken::of(failed))?;
                    continue;
                }
            };
            let sent = self.unacked_records();
            self.unacked.clear();
            self.tally.accepted += ack.accepted;
            self.tally.duplicates += ack.duplicates;
            self.tally.refused += ack.refused;
            let unanswered = sent.saturating_sub(ack.accepted + ack.duplicates + ack.refused);
            self.tally.unacknowledged += unanswered;
            if ack.refused > 0 || unanswered > 0 {
                return Err(PlaneError::Refused {
                    refused: ack.refused + unanswered,
                    sent,
                    reason: ack.reason,
                });
            }
            return Ok(());
        }
    }

    fn tally(&self) -> Option<SinkTally> {
        Some(self.tally)
    }
}

/// The actor side of gRPC policy delivery: a background `WatchPolicy` stream keeps the newest
/// version; [`PolicySource::poll`] takes it. A broken stream is reported once by `poll` as
/// [`PlaneError::Disconnected`]. `Send`, not `Sync`.
pub struct GrpcPolicySource {
    latest: Arc<Mutex<Latest>>,
    task: JoinHandle<()>,
}

#[derive(Default)]
struct Latest {
    policy: Option<PolicyUpdate>,
    error: Option<String>,
}

impl GrpcPolicySource {
    /// Starts watching policies of run `run_id` / `incarnation` for `actor_id` (whose
    /// registration credential is `secret`) on `handle`.
    pub fn start(
        handle: &Handle,
        mut client: DataClient,
        run_id: &str,
        incarnation: u64,
        actor_id: u64,
        secret: &ActorSecret,
    ) -> Self {
        let latest = Arc::new(Mutex::new(Latest::default()));
        let shared = latest.clone();
        let request = pb::PolicyRequest {
            run: Some(pb::RunRef {
                run_id: run_id.to_owned(),
                incarnation,
            }),
            actor_id,
            have_version: 0,
            actor_secret: crate::Bytes::copy_from_slice(secret),
        };
        let task = handle.spawn(async move {
            let fail = |e: String| shared.lock().expect("policy slot").error = Some(e);
            let mut stream = match client.watch_policy(request).await {
                Ok(r) => r.into_inner(),
                Err(status) => return fail(status.message().to_owned()),
            };
            loop {
                match stream.message().await {
                    Ok(Some(snap)) => {
                        let mut weights = Vec::new();
                        if let Err(e) = floats::decode_into("weights", &snap.weights, &mut weights) {
                            return fail(e.to_string());
                        }
                        shared.lock().expect("policy slot").policy = Some(PolicyUpdate {
                            version: snap.version,
                            exploration_sigma: snap.exploration_sigma,
                            weights,
                        });
                    }
                    Ok(None) => return fail("the learner ended the policy stream".into()),
                    Err(status) => return fail(status.message().to_owned()),
                }
            }
        });
        Self { latest, task }
    }
}

impl Drop for GrpcPolicySource {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl PolicySource for GrpcPolicySource {
    fn poll(&mut self, have: Option<u64>) -> Result<Option<PolicyUpdate>, PlaneError> {
        let mut l = self.latest.lock().expect("policy slot");
        let newer = l
            .policy
            .as_ref()
            .is_some_and(|p| have.is_none_or(|h| p.version > h));
        if newer {
            return Ok(l.policy.take());
        }
        match l.error.take() {
            Some(e) => Err(disconnected(e)),
            None => Ok(None),
        }
    }
}
