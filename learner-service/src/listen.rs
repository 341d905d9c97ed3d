//! The accept loops of the learner's servers (TCP and Unix socket): a cap on connections served
//! at once, a deadline for a connection's first bytes, `TCP_NODELAY`, back-off instead of a
//! busy loop when accepting fails for lack of file descriptors, and the open-file limit raised
//! at start with room kept for the learner's own files.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::sync::{mpsc, OwnedSemaphorePermit, Semaphore};
use tokio::time::Sleep;
use tokio_stream::wrappers::ReceiverStream;
use tonic::transport::server::Connected;

/// Bytes of the HTTP/2 connection preface (`PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n`); a TLS
/// ClientHello is longer. A connection that has sent fewer within the handshake timeout is
/// closed.
const PREFACE_LEN: usize = 24;

/// File descriptors kept free for the learner itself (checkpoint files, `status.json`,
/// TensorBoard, the shared-memory services, a resume's reads) when the connection cap is fitted
/// to the open-file limit.
pub const FDS_RESERVED: u64 = 32;

/// The longest pause of an accept loop that keeps failing (e.g. `EMFILE`).
const MAX_BACKOFF: Duration = Duration::from_secs(1);

/// The connection cap is logged at most once this often per listener.
const CAP_REPORT_EVERY: Duration = Duration::from_secs(10);

/// The limits every accepted connection is held to; shared by the learner's servers.
#[derive(Clone)]
pub struct ConnectionLimits {
    /// One permit per connection being served.
    slots: Arc<Semaphore>,
    /// The cap, for the log line.
    max: usize,
    /// How long a connection may take to send its first [`PREFACE_LEN`] bytes.
    handshake: Duration,
}

impl ConnectionLimits {
    /// At most `max` connections at once (at least one), each with `handshake` to start.
    pub fn new(max: usize, handshake: Duration) -> Self {
        let max = max.max(1);
        Self {
            slots: Arc::new(Semaphore::new(max)),
            max,
            handshake,
        }
    }
}

/// Raises the soft open-file limit to the hard one and returns the connection cap that leaves
/// [`FDS_RESERVED`] descriptors free besides those open now: `wanted`, or less when the limit
/// is lower (with a warning).
pub fn fit_connections_to_fd_limit(wanted: usize) -> usize {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit read and write the one struct passed.
    let soft = unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut limit) != 0 {
            tracing::warn!(
                "cannot read the open-file limit ({}); serving up to {wanted} connections",
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
    let room = soft.saturating_sub(open + FDS_RESERVED).max(1);
    if (wanted as u64) > room {
        tracing::warn!(
            open_file_limit = soft,
            open_now = open,
            reserved = FDS_RESERVED,
            "the open-file limit leaves room for {room} connections; serving at most that many \
             (not [service] max_connections = {wanted})"
        );
        room as usize
    } else {
        wanted
    }
}

/// A listener the accept loop can drive.
pub trait Listener: Send + 'static {
    /// The accepted connection.
    type Io: AsyncRead + AsyncWrite + Connected + Unpin + Send + 'static;
    /// Accepts one connection.
    fn poll_accept(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<Self::Io>>;
}

impl Listener for tokio::net::TcpListener {
    type Io = tokio::net::TcpStream;
    fn poll_accept(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<Self::Io>> {
        tokio::net::TcpListener::poll_accept(self, cx).map_ok(|(stream, _)| {
            // Small replies (Register's run spec spans segments) must not wait for delayed
            // acknowledgements: Nagle's algorithm cost a Register about 40 ms.
            let _ = stream.set_nodelay(true);
            stream
        })
    }
}

impl Listener for tokio::net::UnixListener {
    type Io = tokio::net::UnixStream;
    fn poll_accept(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<Self::Io>> {
        tokio::net::UnixListener::poll_accept(self, cx).map_ok(|(stream, _)| stream)
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

/// Accepts connections of `listener` (named `label` in logs) under `limits` on the current
/// runtime and yields them for a server's `serve_with_incoming*`. The loop ends when the
/// server drops the stream.
pub fn incoming<L: Listener>(
    mut listener: L,
    limits: ConnectionLimits,
    label: &'static str,
) -> ReceiverStream<io::Result<Guarded<L::Io>>> {
    let (tx, rx) = mpsc::channel(1);
    tokio::spawn(async move {
        let mut backoff = Duration::from_millis(10);
        // When the cap was last reported, and how often it was reached since: one line per
        // [`CAP_REPORT_EVERY`] however many connections queue.
        let mut reported: Option<tokio::time::Instant> = None;
        let mut reached = 0u64;
        loop {
            let slot = match limits.slots.clone().try_acquire_owned() {
                Ok(slot) => slot,
                Err(_) => {
                    reached += 1;
                    if reported.is_none_or(|t| t.elapsed() >= CAP_REPORT_EVERY) {
                        tracing::warn!(
                            listener = label,
                            max_connections = limits.max,
                            times = reached,
                            "connection limit reached; new connections wait until one closes"
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
            let io = loop {
                match std::future::poll_fn(|cx| listener.poll_accept(cx)).await {
                    Ok(io) => {
                        backoff = Duration::from_millis(10);
                        break io;
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
            let guarded = Guarded {
                io,
                _slot: slot,
                handshake: Some(Box::pin(tokio::time::sleep(limits.handshake))),
                read: 0,
            };
            if tx.send(Ok(guarded)).await.is_err() {
                return;
            }
        }
    });
    ReceiverStream::new(rx)
}

/// An accepted connection: holds its place under the connection cap until it closes, and
/// fails its reads once the handshake deadline passes before [`PREFACE_LEN`] bytes arrived
/// (the server then closes it).
pub struct Guarded<IO> {
    io: IO,
    _slot: OwnedSemaphorePermit,
    /// Until the preface is read.
    handshake: Option<Pin<Box<Sleep>>>,
    /// Bytes read so far (counted up to the preface).
    read: usize,
}

impl<IO: AsyncRead + Unpin> AsyncRead for Guarded<IO> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = &mut *self;
        let before = buf.filled().len();
        match Pin::new(&mut this.io).poll_read(cx, buf) {
            Poll::Ready(Ok(())) => {
                if this.handshake.is_some() {
                    this.read += buf.filled().len() - before;
                    if this.read >= PREFACE_LEN {
                        this.handshake = None;
                    }
                }
                Poll::Ready(Ok(()))
            }
            Poll::Pending => {
                let expired = this
                    .handshake
                    .as_mut()
                    .is_some_and(|deadline| deadline.as_mut().poll(cx).is_ready());
                if expired {
                    Poll::Ready(Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        "no HTTP/2 preface or TLS handshake within [service] handshake_timeout_ms",
                    )))
                } else {
                    Poll::Pending
                }
            }
            other => other,
        }
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

impl<IO: Connected> Connected for Guarded<IO> {
    type ConnectInfo = IO::ConnectInfo;
    fn connect_info(&self) -> Self::ConnectInfo {
        self.io.connect_info()
    }
}
