//! The accept loops of the learner's servers (TCP and Unix socket), each with its own budget of
//! connections: a cap on connections served at once, a cap per source address (TCP), a
//! deadline for a connection's first bytes and one for its first request with the run token,
//! `TCP_NODELAY`, back-off instead of a busy loop when accepting fails for lack of file
//! descriptors, and the open-file limit raised at start with room kept for the learner's own
//! files. Every connection closed or refused here is counted ([`ConnectionStats`], in
//! `status.json`) and logged with the peer and the cause.

use std::collections::{HashMap, VecDeque};
use std::fmt;
use std::future::Future;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::sync::{mpsc, OwnedSemaphorePermit, Semaphore};
use tokio::time::Sleep;
use tokio_stream::wrappers::ReceiverStream;
use tonic::transport::server::Connected;

use crate::authority::AuthorityFix;
use crate::status::{ConnectionStatus, ListenerStatus};

/// Bytes of the HTTP/2 connection preface (`PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n`); a TLS
/// ClientHello is longer. A connection that has sent fewer within the handshake timeout is
/// closed.
const PREFACE_LEN: usize = 24;

/// File descriptors kept free for the learner itself (checkpoint files, `status.json`,
/// TensorBoard, the shared-memory services, a resume's reads) when the connection caps are
/// fitted to the open-file limit.
pub const FDS_RESERVED: u64 = 32;

/// The longest pause of an accept loop that keeps failing (e.g. `EMFILE`).
const MAX_BACKOFF: Duration = Duration::from_secs(1);

/// The connection cap is logged at most once this often per listener.
const CAP_REPORT_EVERY: Duration = Duration::from_secs(10);

/// Refusals of each cause logged (with the peer) before only every 1000th is.
const REFUSALS_LOGGED: u64 = 20;

/// Whether the `total`-th refusal of a cause is logged.
fn logged(total: u64) -> bool {
    total <= REFUSALS_LOGGED || total.is_multiple_of(1000)
}

/// Which of the learner's two listeners.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ListenerKind {
    /// `[service] listen`.
    Tcp,
    /// `learner.sock` in the run directory.
    Unix,
}

impl ListenerKind {
    /// Its name in logs.
    fn label(self) -> &'static str {
        match self {
            Self::Tcp => "tcp",
            Self::Unix => "unix",
        }
    }
}

/// Who is at the other end of a connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Peer {
    /// A TCP peer.
    Tcp(SocketAddr),
    /// A process on this host, through the Unix socket.
    Unix,
}

impl fmt::Display for Peer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Tcp(addr) => write!(f, "tcp {addr}"),
            Self::Unix => f.write_str("the unix socket"),
        }
    }
}

/// What a connection and the requests it carries share: who the peer is and whether it has
/// made a request with the run token.
#[derive(Debug)]
struct ConnState {
    peer: Peer,
    authenticated: AtomicBool,
    /// Closed to make room at a connection cap (it had not made a request with the token).
    evicted: AtomicBool,
    /// The task reading the connection, woken when it is evicted.
    reader: Mutex<Option<Waker>>,
}

impl ConnState {
    fn new(peer: Peer) -> Self {
        Self {
            peer,
            authenticated: AtomicBool::new(false),
            evicted: AtomicBool::new(false),
            reader: Mutex::new(None),
        }
    }

    /// Whether it can be evicted: open, no request with the token yet, not evicted already.
    fn evictable(&self) -> bool {
        !self.authenticated.load(Ordering::Acquire) && !self.evicted.load(Ordering::Acquire)
    }

    /// Closes the connection (its next read fails) unless it has authenticated by then.
    fn evict(&self) {
        self.evicted.store(true, Ordering::Release);
        if let Some(reader) = self.reader.lock().expect("connection waker").take() {
            reader.wake();
        }
    }
}

/// The connect info of every learner connection, in each request's extensions: names the peer
/// and lets the run-token check mark the connection as authenticated.
#[derive(Debug, Clone)]
pub struct PeerInfo(Arc<ConnState>);

impl PeerInfo {
    /// The connection of a request (from its extensions), if it came through these listeners.
    pub fn of(extensions: &http::Extensions) -> Option<&PeerInfo> {
        extensions.get::<PeerInfo>()
    }

    /// The peer.
    pub fn peer(&self) -> Peer {
        self.0.peer
    }

    /// A key for the connection, the same for every request it carries while it is open.
    pub fn key(&self) -> usize {
        Arc::as_ptr(&self.0) as usize
    }

    /// Records that the connection made a request with the run token: the deadline of
    /// `[service] auth_deadline_ms` no longer applies to it.
    pub fn mark_authenticated(&self) {
        self.0.authenticated.store(true, Ordering::Release);
    }
}

/// The peer named in `extensions` (a request's), for log lines.
pub fn peer_name(extensions: &http::Extensions) -> String {
    PeerInfo::of(extensions).map_or_else(|| "an unknown peer".to_owned(), |p| p.peer().to_string())
}

/// Counters of one listener.
#[derive(Debug, Default)]
struct ListenerCounters {
    cap: AtomicU64,
    accepted: AtomicU64,
    open: AtomicU64,
    cap_reached: AtomicU64,
}

impl ListenerCounters {
    fn snapshot(&self) -> ListenerStatus {
        ListenerStatus {
            cap: self.cap.load(Ordering::Relaxed),
            accepted: self.accepted.load(Ordering::Relaxed),
            open: self.open.load(Ordering::Relaxed),
            cap_reached: self.cap_reached.load(Ordering::Relaxed),
        }
    }
}

/// What the learner's servers refused, closed or repaired before serving it (see
/// [`ConnectionStatus`]); shared by both listeners and the services, shown in `status.json`.
#[derive(Debug)]
pub struct ConnectionStats {
    tcp: ListenerCounters,
    unix: ListenerCounters,
    refused_per_address: AtomicU64,
    closed_no_preface: AtomicU64,
    closed_unauthenticated: AtomicU64,
    undecodable_requests: AtomicU64,
    oversized_requests: AtomicU64,
    closed_for_room: AtomicU64,
    policy_streams_refused: AtomicU64,
    policy_streams_refused_per_address: AtomicU64,
    policy_streams_replaced: AtomicU64,
    policy_streams_unfinished: AtomicU64,
    registrations_refused_per_address: AtomicU64,
    messages_ended_for_room: AtomicU64,
    messages_past_deadline: AtomicU64,
    authorities_rewritten: Arc<AtomicU64>,
    /// Run tokens refused (counted with the other refusals of records; here for the log only).
    tokens_refused: AtomicU64,
}

impl Default for ConnectionStats {
    fn default() -> Self {
        Self {
            tcp: ListenerCounters::default(),
            unix: ListenerCounters::default(),
            refused_per_address: AtomicU64::new(0),
            closed_no_preface: AtomicU64::new(0),
            closed_unauthenticated: AtomicU64::new(0),
            undecodable_requests: AtomicU64::new(0),
            oversized_requests: AtomicU64::new(0),
            closed_for_room: AtomicU64::new(0),
            policy_streams_refused: AtomicU64::new(0),
            policy_streams_refused_per_address: AtomicU64::new(0),
            policy_streams_replaced: AtomicU64::new(0),
            policy_streams_unfinished: AtomicU64::new(0),
            registrations_refused_per_address: AtomicU64::new(0),
            messages_ended_for_room: AtomicU64::new(0),
            messages_past_deadline: AtomicU64::new(0),
            authorities_rewritten: Arc::new(AtomicU64::new(0)),
            tokens_refused: AtomicU64::new(0),
        }
    }
}

/// A cause of refusal counted in [`ConnectionStats`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cause {
    /// Over `max_connections_per_ip`.
    PerAddress,
    /// No preface within `handshake_timeout_ms`.
    NoPreface,
    /// No request with the run token within `auth_deadline_ms`.
    Unauthenticated,
    /// A request's message did not decode.
    Undecodable,
    /// A request's message was over the size limit.
    Oversized,
    /// Closed without the run token to make room at a connection cap.
    Evicted,
    /// A `WatchPolicy` stream over `max_policy_streams`.
    PolicyStreamsFull,
    /// A `WatchPolicy` stream over `policy_streams_per_ip`.
    PolicyStreamsPerAddress,
    /// A registration's older `WatchPolicy` stream ended by a newer one (not a refusal of
    /// the newer one).
    PolicyStreamReplaced,
    /// A `WatchPolicy` stream that had not sent its version when `[service]
    /// policy_send_grace_ms` had passed since a newer one was published.
    PolicyStreamUnfinished,
    /// A `Register` over `[service] registrations_per_ip`.
    RegistrationsPerAddress,
    /// An incomplete request message ended to keep `[service] max_incomplete_bytes` or
    /// `max_incomplete_bytes_per_connection`.
    MessageEnded,
    /// A request message not complete within `[service] message_deadline_ms`.
    MessageDeadline,
}

impl ConnectionStats {
    fn listener(&self, kind: ListenerKind) -> &ListenerCounters {
        match kind {
            ListenerKind::Tcp => &self.tcp,
            ListenerKind::Unix => &self.unix,
        }
    }

    fn counter(&self, cause: Cause) -> &AtomicU64 {
        match cause {
            Cause::PerAddress => &self.refused_per_address,
            Cause::NoPreface => &self.closed_no_preface,
            Cause::Unauthenticated => &self.closed_unauthenticated,
            Cause::Undecodable => &self.undecodable_requests,
            Cause::Oversized => &self.oversized_requests,
            Cause::Evicted => &self.closed_for_room,
            Cause::PolicyStreamsFull => &self.policy_streams_refused,
            Cause::PolicyStreamsPerAddress => &self.policy_streams_refused_per_address,
            Cause::PolicyStreamReplaced => &self.policy_streams_replaced,
            Cause::PolicyStreamUnfinished => &self.policy_streams_unfinished,
            Cause::RegistrationsPerAddress => &self.registrations_refused_per_address,
            Cause::MessageEnded => &self.messages_ended_for_room,
            Cause::MessageDeadline => &self.messages_past_deadline,
        }
    }

    /// Counts a refusal of `cause` and logs it with `peer` and `why` (the first
    /// [`REFUSALS_LOGGED`] of the cause, then every 1000th).
    pub fn refuse(&self, cause: Cause, peer: &dyn fmt::Display, why: &dyn fmt::Display) {
        let total = self.counter(cause).fetch_add(1, Ordering::Relaxed) + 1;
        if logged(total) {
            tracing::warn!(peer = %peer, cause = ?cause, total, "refused: {why}");
        }
    }

    /// Logs a refused run token with `peer` (the first [`REFUSALS_LOGGED`], then every
    /// 1000th; the token check counts them, as `unauthenticated` in `refused`).
    pub fn log_token_refusal(&self, peer: &dyn fmt::Display, why: &dyn fmt::Display) {
        let total = self.tokens_refused.fetch_add(1, Ordering::Relaxed) + 1;
        if logged(total) {
            tracing::warn!(peer = %peer, total, "refused: {why}");
        }
    }

    /// The counters for `status.json`.
    pub fn snapshot(&self) -> ConnectionStatus {
        let load = |c: &AtomicU64| c.load(Ordering::Relaxed);
        ConnectionStatus {
            tcp: self.tcp.snapshot(),
            unix: self.unix.snapshot(),
            refused_per_address: load(&self.refused_per_address),
            closed_no_preface: load(&self.closed_no_preface),
            closed_unauthenticated: load(&self.closed_unauthenticated),
            undecodable_requests: load(&self.undecodable_requests),
            oversized_requests: load(&self.oversized_requests),
            closed_for_room: load(&self.closed_for_room),
            policy_streams_refused: load(&self.policy_streams_refused),
            policy_streams_refused_per_address: load(&self.policy_streams_refused_per_address),
            policy_streams_replaced: load(&self.policy_streams_replaced),
            policy_streams_unfinished: load(&self.policy_streams_unfinished),
            registrations_refused_per_address: load(&self.registrations_refused_per_address),
            messages_ended_for_room: load(&self.messages_ended_for_room),
            messages_past_deadline: load(&self.messages_past_deadline),
            authorities_rewritten: load(&self.authorities_rewritten),
        }
    }
}

/// Open connections per source address of one listener.
type ByAddress = Arc<Mutex<HashMap<IpAddr, usize>>>;

/// The limits every accepted connection of one listener is held to.
#[derive(Clone)]
pub struct ConnectionLimits {
    /// One permit per connection being served.
    slots: Arc<Semaphore>,
    /// The cap, for the log line.
    max: usize,
    /// Most connections from one source address (TCP).
    per_address: usize,
    /// Open connections per source address.
    by_address: ByAddress,
    /// The connections served, oldest first (closed ones are dropped when met).
    served: Arc<Mutex<VecDeque<Weak<ConnState>>>>,
    /// How long a connection may take to send its first [`PREFACE_LEN`] bytes.
    handshake: Duration,
    /// How long a connection may take to make its first request with the run token.
    auth_deadline: Duration,
    /// Where refusals are counted.
    stats: Arc<ConnectionStats>,
}

impl ConnectionLimits {
    /// At most `max` connections at once (at least one) and `per_address` from one source
    /// address; each with `handshake` to start and `auth_deadline` to make a request with the
    /// run token; refusals counted in `stats`.
    pub fn new(
        max: usize,
        per_address: usize,
        handshake: Duration,
        auth_deadline: Duration,
        stats: Arc<ConnectionStats>,
    ) -> Self {
        let max = max.max(1);
        Self {
            slots: Arc::new(Semaphore::new(max)),
            max,
            per_address: per_address.max(1),
            by_address: Arc::new(Mutex::new(HashMap::new())),
            served: Arc::new(Mutex::new(VecDeque::new())),
            handshake,
            auth_deadline,
            stats,
        }
    }

    /// Evicts the oldest connection served (from address `ip`, when given) that has not made a
    /// request with the run token, to make room for `newcomer` at the cap `key`: counted and
    /// logged with both peers. Returns whether one was evicted.
    fn evict_for(&self, ip: Option<IpAddr>, newcomer: &Peer, key: &str) -> bool {
        let mut served = self.served.lock().expect("served connections lock");
        served.retain(|c| c.strong_count() > 0);
        let victim = served.iter().filter_map(Weak::upgrade).find(|c| {
            c.evictable() && ip.is_none_or(|ip| matches!(c.peer, Peer::Tcp(a) if a.ip().to_canonical() == ip))
        });
        let Some(victim) = victim else {
            return false;
        };
        victim.evict();
        self.stats.refuse(
            Cause::Evicted,
            &victim.peer,
            &format_args!(
                "it had made no request with the run token and {newcomer} needed its place \
                 ([service] {key}); closed"
            ),
        );
        true
    }

    /// A place for a connection from `peer` under the per-address cap, or the number already
    /// open from its address when it is full. Unix-socket peers have no address. With `force`
    /// the place is taken even over the cap (another connection of the address was evicted
    /// and gives its place back when it closes).
    fn take_address(&self, peer: Peer, force: bool) -> Result<Option<AddressSlot>, usize> {
        let Peer::Tcp(addr) = peer else {
            return Ok(None);
        };
        // An IPv4 peer of a dual-stack socket counts with its IPv4 address.
        let ip = addr.ip().to_canonical();
        let mut open = self.by_address.lock().expect("address counts lock");
        let n = open.entry(ip).or_insert(0);
        if *n >= self.per_address && !force {
            return Err(*n);
        }
        *n += 1;
        Ok(Some(AddressSlot {
            ip,
            by_address: self.by_address.clone(),
        }))
    }
}

/// A connection's place under its address's cap, given back when it closes.
struct AddressSlot {
    ip: IpAddr,
    by_address: ByAddress,
}

impl Drop for AddressSlot {
    fn drop(&mut self) {
        let mut open = self.by_address.lock().expect("address counts lock");
        if let Some(n) = open.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                open.remove(&self.ip);
            }
        }
    }
}

/// Raises the soft open-file limit to the hard one and returns the connection cap of each of
/// `listeners` listeners that leaves [`FDS_RESERVED`] descriptors free besides those open now:
/// `wanted`, or less when the limit is lower (with a warning).
pub fn fit_connections_to_fd_limit(wanted: usize, listeners: usize) -> usize {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit read and write the one struct passed.
    let soft = unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) != 0 {
            tracing::warn!(
                "cannot read the open-file limit ({}); serving up to {wanted} connections per \
                 listener",
                io::Error::last_os_error()
            );
            return wanted;
        }
        if limit.rlim_cur < limit.rlim_max {
            let raised = libc::rlimit {
                rlim_cur: limit.rlim_max,
                rlim_max: limit.rlim_max,
            };
            if libc::setrlimit(libc::RLIMIT_NOFILE, &raised) == 0 {
                tracing::info!(
                    from = limit.rlim_cur,
                    to = limit.rlim_max,
                    "raised the open-file limit to the hard limit"
                );
                limit.rlim_cur = limit.rlim_max;
            }
        }
        limit.rlim_cur
    };
    let open = std::fs::read_dir("/proc/self/fd").map_or(0, |d| d.count() as u64);
    let room = (soft.saturating_sub(open + FDS_RESERVED) / listeners.max(1) as u64).max(1);
    if (wanted as u64) > room {
        tracing::warn!(
            open_file_limit = soft,
            open_now = open,
            reserved = FDS_RESERVED,
            "the open-file limit leaves room for {room} connections per listener ({listeners} \
             listeners); serving at most that many (not [service] max_connections = {wanted})"
        );
        room as usize
    } else {
        wanted
    }
}

/// A listener the accept loop can drive.
pub trait Listener: Send + 'static {
    /// The accepted connection.
    type Io: AsyncRead + AsyncWrite + Unpin + Send + 'static;
    /// Which listener this is.
    const KIND: ListenerKind;
    /// Accepts one connection, with its peer.
    fn poll_accept(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<(Self::Io, Peer)>>;
}

impl Listener for tokio::net::TcpListener {
    type Io = tokio::net::TcpStream;
    const KIND: ListenerKind = ListenerKind::Tcp;
    fn poll_accept(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<(Self::Io, Peer)>> {
        tokio::net::TcpListener::poll_accept(self, cx).map_ok(|(stream, addr)| {
            // Small replies (Register's run spec spans segments) must not wait for delayed
            // acknowledgements: Nagle's algorithm cost a Register about 40 ms.
            let _ = stream.set_nodelay(true);
            (stream, Peer::Tcp(addr))
        })
    }
}

/// The learner's Unix socket: its connections' `:authority` is made acceptable on the way in
/// (see [`crate::authority`]), counted in `rewritten`.
pub struct UnixSocket {
    /// The bound socket.
    pub listener: tokio::net::UnixListener,
    /// Counts the rewritten authorities.
    rewritten: Arc<AtomicU64>,
}

impl UnixSocket {
    /// `listener`, its rewrites counted in `stats`.
    pub fn new(listener: tokio::net::UnixListener, stats: &ConnectionStats) -> Self {
        Self {
            listener,
            rewritten: stats.authorities_rewritten.clone(),
        }
    }
}

impl Listener for UnixSocket {
    type Io = AuthorityFix<tokio::net::UnixStream>;
    const KIND: ListenerKind = ListenerKind::Unix;
    fn poll_accept(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<(Self::Io, Peer)>> {
        self.listener
            .poll_accept(cx)
            .map_ok(|(stream, _)| (AuthorityFix::new(stream, self.rewritten.clone()), Peer::Unix))
    }
}

/// The source address of a TCP peer (an IPv4 peer of a dual-stack socket as IPv4).
fn peer_ip(peer: &Peer) -> Option<IpAddr> {
    match peer {
        Peer::Tcp(addr) => Some(addr.ip().to_canonical()),
        Peer::Unix => None,
    }
}

/// Whether an accept error means the process or system is out of a resource (descriptors,
/// buffers, memory): then accepting again at once would fail again.
fn out_of_resources(e: &io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(libc::EMFILE | libc::ENFILE | libc::ENOBUFS | libc::ENOMEM)
    )
}

/// Accepts connections of `listener` under `limits` on the current runtime and yields them for
/// a server's `serve_with_incoming*`. The loop ends when the server drops the stream.
pub fn incoming<L: Listener>(
    mut listener: L,
    limits: ConnectionLimits,
) -> ReceiverStream<io::Result<Guarded<L::Io>>> {
    let label = L::KIND.label();
    limits
        .stats
        .listener(L::KIND)
        .cap
        .store(limits.max as u64, Ordering::Relaxed);
    let (tx, rx) = mpsc::channel(1);
    tokio::spawn(async move {
        let stats = limits.stats.clone();
        let counters = stats.listener(L::KIND);
        let mut backoff = Duration::from_millis(10);
        // When the cap was last reported, and how often it was reached since: one line per
        // [`CAP_REPORT_EVERY`] however many connections queue.
        let mut reported: Option<tokio::time::Instant> = None;
        let mut reached = 0u64;
        loop {
            let (io, peer) = loop {
                match std::future::poll_fn(|cx| listener.poll_accept(cx)).await {
                    Ok(accepted) => {
                        backoff = Duration::from_millis(10);
                        break accepted;
                    }
                    Err(e) if out_of_resources(&e) => {
                        tracing::warn!(
                            listener = label,
                            pause_ms = backoff.as_millis() as u64,
                            "cannot accept a connection ({e}); pausing"
                        );
                        tokio::time::sleep(backoff).await;
                        backoff = (backoff * 2).min(MAX_BACKOFF);
                    }
                    Err(e) => tracing::debug!(listener = label, "accept failed: {e}"),
                }
            };
            counters.accepted.fetch_add(1, Ordering::Relaxed);
            // At the cap, the oldest connection without the run token makes room (token-less
            // peers never hold places an actor needs); when every one has the token, the new
            // connection waits until one closes.
            let slot = match limits.slots.clone().try_acquire_owned() {
                Ok(slot) => slot,
                Err(_) => {
                    reached += 1;
                    counters.cap_reached.fetch_add(1, Ordering::Relaxed);
                    if !limits.evict_for(None, &peer, "max_connections")
                        && reported.is_none_or(|t| t.elapsed() >= CAP_REPORT_EVERY)
                    {
                        tracing::warn!(
                            listener = label,
                            max_connections = limits.max,
                            times = reached,
                            "connection limit reached and every connection has made a request \
                             with the run token; new connections wait until one closes"
                        );
                        reported = Some(tokio::time::Instant::now());
                        reached = 0;
                    }
                    match limits.slots.clone().acquire_owned().await {
                        Ok(slot) => slot,
                        Err(_) => return,
                    }
                }
            };
            let address = match limits.take_address(peer, false) {
                Ok(address) => address,
                Err(_)
                    if peer_ip(&peer)
                        .is_some_and(|ip| limits.evict_for(Some(ip), &peer, "max_connections_per_ip")) =>
                {
                    limits
                        .take_address(peer, true)
                        .expect("a forced place is always given")
                }
                Err(open) => {
                    // Closed at once (dropped); its place goes to the next connection.
                    stats.refuse(
                        Cause::PerAddress,
                        &peer,
                        &format_args!(
                            "{open} connections from its address are open ([service] \
                             max_connections_per_ip = {}); closed",
                            limits.per_address
                        ),
                    );
                    continue;
                }
            };
            counters.open.fetch_add(1, Ordering::Relaxed);
            let conn = Arc::new(ConnState::new(peer));
            limits
                .served
                .lock()
                .expect("served connections lock")
                .push_back(Arc::downgrade(&conn));
            let guarded = Guarded {
                io,
                _slot: slot,
                _address: address,
                conn,
                kind: L::KIND,
                stats: stats.clone(),
                handshake: Some(Box::pin(tokio::time::sleep(limits.handshake))),
                auth_deadline: Some(Box::pin(tokio::time::sleep(limits.auth_deadline))),
                auth_deadline_ms: limits.auth_deadline.as_millis() as u64,
                closed: None,
                read: 0,
            };
            if tx.send(Ok(guarded)).await.is_err() {
                return;
            }
        }
    });
    ReceiverStream::new(rx)
}

/// An accepted connection: holds its places under the connection caps until it closes, and
/// fails its reads (the server then closes it) once the handshake deadline passes before
/// [`PREFACE_LEN`] bytes arrived, or the authentication deadline passes before a request with
/// the run token.
pub struct Guarded<IO> {
    io: IO,
    _slot: OwnedSemaphorePermit,
    _address: Option<AddressSlot>,
    conn: Arc<ConnState>,
    kind: ListenerKind,
    stats: Arc<ConnectionStats>,
    /// Until the preface is read.
    handshake: Option<Pin<Box<Sleep>>>,
    /// Until a request with the run token is made.
    auth_deadline: Option<Pin<Box<Sleep>>>,
    /// `[service] auth_deadline_ms`, for the error.
    auth_deadline_ms: u64,
    /// Why the connection was closed, once it was (every later read fails the same way).
    closed: Option<&'static str>,
    /// Bytes read so far (counted up to the preface).
    read: usize,
}

impl<IO> Guarded<IO> {
    /// Whether a deadline has passed (polling them, so that the task wakes when one does):
    /// then the reason, counted and logged once.
    fn expired(&mut self, cx: &mut Context<'_>) -> Option<&'static str> {
        if self.closed.is_some() {
            return self.closed;
        }
        if self.auth_deadline.is_some() && !self.conn.authenticated.load(Ordering::Acquire) {
            if self.conn.evicted.load(Ordering::Acquire) {
                // Counted and logged by the eviction.
                self.closed = Some("closed to make room at a connection cap, without the run token");
                self.handshake = None;
                self.auth_deadline = None;
                return self.closed;
            }
            *self.conn.reader.lock().expect("connection waker") = Some(cx.waker().clone());
        }
        let passed = |deadline: &mut Option<Pin<Box<Sleep>>>, cx: &mut Context<'_>| {
            deadline.as_mut().is_some_and(|d| d.as_mut().poll(cx).is_ready())
        };
        if passed(&mut self.handshake, cx) {
            let why = "no HTTP/2 preface or TLS handshake within [service] handshake_timeout_ms";
            self.stats
                .refuse(Cause::NoPreface, &self.conn.peer, &format_args!("{why}; closed"));
            self.closed = Some(why);
        } else if self.auth_deadline.is_some() {
            if self.conn.authenticated.load(Ordering::Acquire) {
                self.auth_deadline = None;
            } else if passed(&mut self.auth_deadline, cx) {
                let why = "no request with the run token within [service] auth_deadline_ms";
                self.stats.refuse(
                    Cause::Unauthenticated,
                    &self.conn.peer,
                    &format_args!("{why} ({} ms); closed", self.auth_deadline_ms),
                );
                self.closed = Some(why);
            }
        }
        if self.closed.is_some() {
            self.handshake = None;
            self.auth_deadline = None;
        }
        self.closed
    }
}

impl<IO> Drop for Guarded<IO> {
    fn drop(&mut self) {
        self.stats
            .listener(self.kind)
            .open
            .fetch_sub(1, Ordering::Relaxed);
    }
}

impl<IO: AsyncRead + Unpin> AsyncRead for Guarded<IO> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = &mut *self;
        if let Some(why) = this.expired(cx) {
            return Poll::Ready(Err(io::Error::new(io::ErrorKind::TimedOut, why)));
        }
        let before = buf.filled().len();
        let read = Pin::new(&mut this.io).poll_read(cx, buf);
        if let Poll::Ready(Ok(())) = read {
            if this.handshake.is_some() {
                this.read += buf.filled().len() - before;
                if this.read >= PREFACE_LEN {
                    this.handshake = None;
                }
            }
        }
        read
    }
}

impl<IO: AsyncWrite + Unpin> AsyncWrite for Guarded<IO> {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.io).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.io).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.io).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.io).poll_shutdown(cx)
    }
}

impl<IO> Connected for Guarded<IO> {
    type ConnectInfo = PeerInfo;
    fn connect_info(&self) -> Self::ConnectInfo {
        PeerInfo(self.conn.clone())
    }
}
