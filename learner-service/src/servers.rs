//! The gRPC control plane (and the gRPC data plane) of a learner: the TCP and Unix-socket
//! servers with their connection limits, the policy channel they stream from, lease expiry and
//! the signal handlers, on one tokio runtime.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use proto::pb;
use tokio::sync::watch;
use tonic::service::Interceptor;

use crate::config::LearnerOptions;
use crate::error::{FileError, StartError};
use crate::run_dir::{write_atomic, ADDR_FILE, OPERATOR_TOKEN_FILE, SOCKET_FILE};
use crate::shared::Shared;
use crate::{budget, control, data, listen, policy_streams, wire_status};

/// HTTP/2 pings every this long on an idle connection; a peer that does not answer within
/// [`KEEPALIVE_TIMEOUT`] is dropped with its streams (a dead host, a cut network).
const KEEPALIVE_INTERVAL: Duration = Duration::from_secs(20);
/// See [`KEEPALIVE_INTERVAL`].
const KEEPALIVE_TIMEOUT: Duration = Duration::from_secs(20);
/// Concurrent requests one connection may have in flight (an actor needs four: heartbeat,
/// assignment or report, the step stream and the policy stream); more wait.
const REQUESTS_PER_CONNECTION: usize = 16;
/// HTTP/2 flow-control window of each request stream: what a peer may send that the learner
/// has not read yet (tonic reads as data arrives; what it holds of incomplete messages is
/// budgeted by [`budget::MessageBudget`]). A step batch (about 190 KB) fits.
const STREAM_WINDOW: u32 = 256 * 1024;
/// The same for a whole connection.
const CONNECTION_WINDOW: u32 = 1024 * 1024;

/// The run-token check ([`proto::auth::ServerAuth`], which counts refusals) that also marks the
/// request's connection as authenticated, lifting its `[service] auth_deadline_ms`, and logs a
/// refusal with the peer.
#[derive(Clone)]
struct ConnectionAuth {
    auth: proto::auth::ServerAuth,
    stats: Arc<listen::ConnectionStats>,
}

impl Interceptor for ConnectionAuth {
    fn call(&mut self, request: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        let peer = listen::PeerInfo::of(request.extensions()).cloned();
        match self.auth.call(request) {
            Ok(request) => {
                if let Some(peer) = peer {
                    peer.mark_authenticated();
                }
                Ok(request)
            }
            Err(status) => {
                let peer = peer.map_or_else(|| "an unknown peer".to_owned(), |p| p.peer().to_string());
                self.stats.log_token_refusal(&peer, &status.message());
                Err(status)
            }
        }
    }
}

/// A gRPC server with the learner's connection limits.
fn server_builder() -> tonic::transport::Server {
    tonic::transport::Server::builder()
        .http2_keepalive_interval(Some(KEEPALIVE_INTERVAL))
        .http2_keepalive_timeout(Some(KEEPALIVE_TIMEOUT))
        .tcp_keepalive(Some(KEEPALIVE_INTERVAL))
        .concurrency_limit_per_connection(REQUESTS_PER_CONNECTION)
        .max_concurrent_streams(REQUESTS_PER_CONNECTION as u32)
        .initial_stream_window_size(STREAM_WINDOW)
        .initial_connection_window_size(CONNECTION_WINDOW)
}

/// Binds a Unix socket at `path` (replacing a stale one from an earlier learner of the run),
/// readable and writable by this user only.
fn bind_unix(runtime: &tokio::runtime::Runtime, path: &Path) -> Result<tokio::net::UnixListener, StartError> {
    use std::os::unix::fs::PermissionsExt;
    // sockaddr_un holds 108 bytes including the terminating NUL.
    if path.as_os_str().len() > 107 {
        return Err(StartError::SocketPath(path.to_path_buf()));
    }
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(FileError::at(format!("cannot remove the old {}", path.display()))(e).into())
        }
        _ => {}
    }
    let _guard = runtime.enter();
    let listener = tokio::net::UnixListener::bind(path)
        .map_err(FileError::at(format!("cannot bind {}", path.display())))?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600))
        .map_err(FileError::at(format!("cannot chmod 600 {}", path.display())))?;
    Ok(listener)
}

/// A server task of the control plane.
pub(crate) type ServerTask = tokio::task::JoinHandle<Result<(), tonic::transport::Error>>;

/// The gRPC control plane (and the gRPC data plane): the runtime, the TCP and Unix-socket
/// servers, the policy channel they stream from, lease expiry and the signal handlers.
pub(crate) struct ControlPlane {
    /// The runtime running the servers.
    pub(crate) runtime: tokio::runtime::Runtime,
    /// The bound TCP address.
    pub(crate) addr: SocketAddr,
    /// Where the training thread publishes policies.
    pub(crate) policy_tx: watch::Sender<Arc<pb::PolicySnapshot>>,
    /// The newest published policy.
    pub(crate) policy: watch::Receiver<Arc<pb::PolicySnapshot>>,
    /// Stops the servers.
    pub(crate) server_stop: watch::Sender<bool>,
    /// The TCP server.
    pub(crate) server: ServerTask,
    /// The Unix socket and its server, when the socket could be bound.
    pub(crate) unix_server: Option<(PathBuf, ServerTask)>,
}

impl ControlPlane {
    /// Binds `[service] listen` (with TLS when configured) and the Unix socket in `run_dir`,
    /// serves the control and data services on both, writes `learner.addr`, and starts lease
    /// expiry and (with `handle_signals`) the SIGTERM/SIGINT handlers.
    pub(crate) fn start(
        opts: &LearnerOptions,
        run_dir: &Path,
        shared: &Arc<Shared>,
    ) -> Result<Self, StartError> {
        let svc = &opts.service;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .thread_name("adp-learner-io")
            .build()
            .map_err(FileError::at("cannot start the tokio runtime"))?;
        let listener = runtime
            .block_on(tokio::net::TcpListener::bind(&svc.listen))
            .map_err(FileError::at(format!("cannot listen on {}", svc.listen)))?;
        let addr = listener
            .local_addr()
            .map_err(FileError::at("cannot read the bound address"))?;
        let (policy_tx, policy_rx) = watch::channel(Arc::new(pb::PolicySnapshot::default()));
        let stats = shared.connections.clone();
        let auth = ConnectionAuth {
            auth: proto::auth::ServerAuth::new(&opts.token, shared.refusals.clone()),
            stats: stats.clone(),
        };
        let operator: Arc<str> =
            proto::auth::read_or_create_token_file(&run_dir.join(OPERATOR_TOKEN_FILE))?.into();
        let mut builder = server_builder();
        if let Some(tls) = &svc.tls {
            builder = builder
                .tls_config(tls.server_config()?)
                .map_err(StartError::Tls)?;
        }
        // Incomplete request messages are budgeted over both listeners and both services.
        let budget = Arc::new(budget::MessageBudget::new(
            budget::BudgetLimits {
                total: usize::try_from(svc.max_incomplete_bytes).unwrap_or(usize::MAX),
                per_connection: usize::try_from(svc.max_incomplete_bytes_per_connection)
                    .unwrap_or(usize::MAX),
                deadline: Duration::from_millis(u64::from(svc.message_deadline_ms)),
            },
            stats.clone(),
        ));
        let control = tonic::service::interceptor::InterceptedService::new(
            // Oversized requests are refused with RESOURCE_EXHAUSTED, undecodable ones with
            // INVALID_ARGUMENT.
            wire_status::WireStatus {
                inner: pb::control_server::ControlServer::new(control::ControlService {
                    shared: shared.clone(),
                    operator,
                })
                .max_decoding_message_size(proto::grpc::MAX_CONTROL_REQUEST_BYTES),
                stats: stats.clone(),
            },
            auth.clone(),
        );
        let policy = policy_rx.clone();
        let data = tonic::service::interceptor::InterceptedService::new(
            wire_status::WireStatus {
                inner: policy_streams::DataRoutes {
                    // Requests are step batches (bounded).
                    inner: pb::data_server::DataServer::new(data::DataService {
                        shared: shared.clone(),
                    })
                    .max_decoding_message_size(proto::grpc::MAX_REQUEST_BYTES),
                    streams: Arc::new(policy_streams::PolicyStreams::new(
                        shared.clone(),
                        policy_rx,
                        svc.max_policy_streams,
                        svc.policy_streams_per_ip,
                        svc.policy_streams_per_actor,
                        Duration::from_millis(u64::from(svc.policy_send_grace_ms)),
                    )),
                },
                stats: stats.clone(),
            },
            auth,
        );
        let control = budget::Budgeted {
            inner: control,
            budget: budget.clone(),
        };
        let data = budget::Budgeted { inner: data, budget };
        // A budget per listener, so that a flood of one cannot lock the other out, each fitted
        // to the open-file limit so that connections can never take the descriptors a
        // checkpoint needs.
        let cap = listen::fit_connections_to_fd_limit(svc.max_connections as usize, 2);
        let limits = || {
            listen::ConnectionLimits::new(
                cap,
                svc.max_connections_per_ip as usize,
                Duration::from_millis(u64::from(svc.handshake_timeout_ms)),
                Duration::from_millis(u64::from(svc.auth_deadline_ms)),
                stats.clone(),
            )
        };
        let _in_runtime = runtime.enter();
        let (server_stop, stop_rx) = watch::channel(false);
        let stopped = |mut rx: watch::Receiver<bool>| async move {
            let _ = rx.wait_for(|s| *s).await;
        };
        // The same services on a Unix socket in the run directory, for actors on this host
        // (sandboxed actors without a network reach the learner only this way). Plain HTTP/2:
        // the socket (mode 0600) never leaves the host; the token is still checked.
        let socket = run_dir.join(SOCKET_FILE);
        let unix_server = match bind_unix(&runtime, &socket) {
            Ok(unix) => Some((
                socket,
                runtime.spawn(
                    server_builder()
                        .add_service(control.clone())
                        .add_service(data.clone())
                        .serve_with_incoming_shutdown(
                            listen::incoming(listen::UnixSocket::new(unix, &stats), limits()),
                            stopped(stop_rx.clone()),
                        ),
                ),
            )),
            Err(why) => {
                tracing::warn!("no Unix socket for local actors ({why}); they use {addr}");
                None
            }
        };
        let router = builder.add_service(control).add_service(data);
        let server = runtime.spawn(
            router.serve_with_incoming_shutdown(listen::incoming(listener, limits()), stopped(stop_rx)),
        );
        write_atomic(&run_dir.join(ADDR_FILE), &format!("{addr}\n"))?;

        // Lease expiry.
        let ticker = shared.clone();
        runtime.spawn(async move {
            let mut every = tokio::time::interval(Duration::from_millis(100));
            loop {
                every.tick().await;
                ticker.expire_leases();
            }
        });
        if opts.handle_signals {
            let s = shared.clone();
            runtime.spawn(async move {
                use tokio::signal::unix::{signal, SignalKind};
                let (Ok(mut term), Ok(mut int)) =
                    (signal(SignalKind::terminate()), signal(SignalKind::interrupt()))
                else {
                    tracing::error!("cannot install signal handlers");
                    return;
                };
                tokio::select! {
                    _ = term.recv() => tracing::info!("SIGTERM: checkpointing and stopping"),
                    _ = int.recv() => tracing::info!("SIGINT: checkpointing and stopping"),
                }
                s.request_stop(true);
            });
        }
        Ok(Self {
            runtime,
            addr,
            policy_tx,
            policy,
            server_stop,
            server,
            unix_server,
        })
    }
}
