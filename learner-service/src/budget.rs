//! A budget for the bytes of request messages that have begun to arrive but are not complete.
//!
//! tonic buffers a request's message until its last byte arrives (up to the service's
//! `max_decoding_message_size`), whatever the HTTP/2 flow-control windows say: it reads every
//! DATA frame as it comes, which hands the window back. A peer that declares 1 MiB messages on
//! many streams and sends all but their last byte made the learner hold a MiB per stream for as
//! long as the peer answered pings. [`Budgeted`] wraps a service and reads each request body
//! through [`BudgetedBody`], which follows the gRPC framing (a 5-byte head with the length,
//! then the message) and charges every byte of a message not yet complete to its connection
//! and to the learner's total:
//!
//! - over `[service] max_incomplete_bytes_per_connection`, the connection's oldest incomplete
//!   message ends; over `max_incomplete_bytes` (all connections together), the learner's
//!   oldest does. Oldest first: an honest message completes within milliseconds of its first
//!   byte, so the ones that end are those a peer keeps unfinished, never the newcomer;
//! - a message not complete within `[service] message_deadline_ms` of its first byte ends.
//!
//! A message that ends fails its request with RESOURCE_EXHAUSTED (the budget) or
//! DEADLINE_EXCEEDED (the deadline); its bytes are released at once. Each is counted in
//! `status.json` (`connections.messages_ended_for_room`, `messages_past_deadline`) and logged
//! with the peer (the first 20 of each cause, then every 1000th).

use std::collections::{BTreeMap, HashMap};
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use http_body::{Body as HttpBody, Frame, SizeHint};
use prost::bytes::Bytes;
use tokio::time::Sleep;
use tonic::body::Body;
use tonic::server::NamedService;
use tonic::Status;

use crate::listen::{Cause, ConnectionStats, Peer, PeerInfo};

/// Bytes of a gRPC message's head (compression flag and length).
const HEAD: usize = 5;

/// The caps and the deadline of a [`MessageBudget`].
#[derive(Debug, Clone, Copy)]
pub struct BudgetLimits {
    /// Incomplete bytes over all connections (`[service] max_incomplete_bytes`).
    pub total: usize,
    /// Incomplete bytes of one connection (`max_incomplete_bytes_per_connection`).
    pub per_connection: usize,
    /// How long a message may take from its first byte to its last (`message_deadline_ms`).
    pub deadline: Duration,
}

/// One incomplete message: whose it is, what it holds, and how to end it.
struct Entry {
    conn: usize,
    peer: Option<Peer>,
    bytes: usize,
    state: Arc<MessageState>,
}

/// What a message's body and the budget share: whether the budget ended it, and the task to
/// wake when it did.
#[derive(Default)]
struct MessageState {
    ended: AtomicBool,
    reader: Mutex<Option<Waker>>,
}

/// The incomplete messages, oldest (smallest id) first, and the bytes they hold.
#[derive(Default)]
struct Table {
    open: BTreeMap<u64, Entry>,
    by_connection: HashMap<usize, usize>,
    total: usize,
    next_id: u64,
}

impl Table {
    /// Removes message `id` and gives its bytes back; its entry if it was still open.
    fn remove(&mut self, id: u64) -> Option<Entry> {
        let entry = self.open.remove(&id)?;
        self.total -= entry.bytes;
        if let Some(n) = self.by_connection.get_mut(&entry.conn) {
            *n -= entry.bytes;
            if *n == 0 {
                self.by_connection.remove(&entry.conn);
            }
        }
        Some(entry)
    }
}

/// The learner's budget of bytes in incomplete request messages (see the module comment).
pub struct MessageBudget {
    limits: BudgetLimits,
    table: Mutex<Table>,
    stats: Arc<ConnectionStats>,
}

impl MessageBudget {
    /// A budget of `limits`, its endings counted in `stats`.
    pub fn new(limits: BudgetLimits, stats: Arc<ConnectionStats>) -> Self {
        Self {
            limits,
            table: Mutex::new(Table::default()),
            stats,
        }
    }

    /// Bytes held by incomplete messages now.
    #[cfg(test)]
    fn held(&self) -> usize {
        self.table.lock().expect("message budget").total
    }

    /// Opens a message of connection `conn` (from `peer`).
    fn open(&self, conn: usize, peer: Option<Peer>) -> (u64, Arc<MessageState>) {
        let state = Arc::new(MessageState::default());
        let mut table = self.table.lock().expect("message budget");
        let id = table.next_id;
        table.next_id += 1;
        table.open.insert(
            id,
            Entry {
                conn,
                peer,
                bytes: 0,
                state: state.clone(),
            },
        );
        (id, state)
    }

    /// Charges `n` more bytes to message `id`, ending the oldest other messages of its
    /// connection, then of the learner, until both caps hold. Returns false when message `id`
    /// alone is over a cap (or was ended already): then it ends itself.
    fn charge(&self, id: u64, n: usize) -> bool {
        let mut table = self.table.lock().expect("message budget");
        let Some(entry) = table.open.get_mut(&id) else {
            return false;
        };
        entry.bytes += n;
        let conn = entry.conn;
        table.total += n;
        *table.by_connection.entry(conn).or_default() += n;
        while table.by_connection.get(&conn).copied().unwrap_or(0) > self.limits.per_connection {
            let oldest = table
                .open
                .iter()
                .find(|(&other, e)| other != id && e.conn == conn)
                .map(|(&other, _)| other);
            let Some(oldest) = oldest else {
                table.remove(id);
                return false;
            };
            self.end(&mut table, oldest, "max_incomplete_bytes_per_connection");
        }
        while table.total > self.limits.total {
            let oldest = table.open.keys().copied().find(|&other| other != id);
            let Some(oldest) = oldest else {
                table.remove(id);
                return false;
            };
            self.end(&mut table, oldest, "max_incomplete_bytes");
        }
        true
    }

    /// Ends message `id` to make room under the cap `key`: its bytes are given back now, its
    /// request fails when its body is next read (its task is woken). Counted and logged.
    fn end(&self, table: &mut Table, id: u64, key: &str) {
        let Some(entry) = table.remove(id) else {
            return;
        };
        entry.state.ended.store(true, Ordering::Release);
        if let Some(reader) = entry.state.reader.lock().expect("message waker").take() {
            reader.wake();
        }
        let peer: &dyn std::fmt::Display = match &entry.peer {
            Some(p) => p,
            None => &"an unknown peer",
        };
        self.stats.refuse(
            Cause::MessageEnded,
            peer,
            &format_args!(
                "its incomplete request message of {} bytes so far was the oldest at [service] \
                 {key}; its request ends",
                entry.bytes
            ),
        );
    }

    /// Gives back the bytes of message `id` (complete, or its request ended).
    fn release(&self, id: u64) {
        self.table.lock().expect("message budget").remove(id);
    }
}

/// A service whose request bodies are read through a [`BudgetedBody`].
#[derive(Clone)]
pub struct Budgeted<S> {
    /// The service.
    pub inner: S,
    /// The budget the bodies are charged to.
    pub budget: Arc<MessageBudget>,
}

impl<S: NamedService> NamedService for Budgeted<S> {
    const NAME: &'static str = S::NAME;
}

impl<S> tower_service::Service<http::Request<Body>> for Budgeted<S>
where
    S: tower_service::Service<http::Request<Body>>,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = S::Future;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, request: http::Request<Body>) -> Self::Future {
        let info = PeerInfo::of(request.extensions()).cloned();
        let budget = self.budget.clone();
        self.inner
            .call(request.map(|body| Body::new(BudgetedBody::new(body, budget, info))))
    }
}

/// The message of a [`BudgetedBody`] being read.
struct Current {
    id: u64,
    state: Arc<MessageState>,
    deadline: Pin<Box<Sleep>>,
    /// Bytes of the head read so far, and the head.
    head_read: usize,
    head: [u8; HEAD],
    /// Bytes of the message after its head still to come (known once the head is read).
    left: usize,
}

/// A request body whose incomplete message is charged to a [`MessageBudget`]; it fails the
/// request when the budget ends the message or its deadline passes.
pub struct BudgetedBody {
    inner: Body,
    budget: Arc<MessageBudget>,
    info: Option<PeerInfo>,
    current: Option<Current>,
    failed: bool,
}

impl BudgetedBody {
    /// `inner` charged to `budget` as a request of the connection `info`.
    fn new(inner: Body, budget: Arc<MessageBudget>, info: Option<PeerInfo>) -> Self {
        Self {
            inner,
            budget,
            info,
            current: None,
            failed: false,
        }
    }

    /// Walks `data` through the gRPC framing, charging the bytes of incomplete messages and
    /// giving back those of messages that complete. Err when the budget ended the message.
    fn account(&mut self, mut data: &[u8]) -> Result<(), ()> {
        while !data.is_empty() {
            let current = match &mut self.current {
                Some(c) => c,
                None => {
                    let conn = self.info.as_ref().map_or(0, PeerInfo::key);
                    let (id, state) = self.budget.open(conn, self.info.as_ref().map(PeerInfo::peer));
                    self.current.insert(Current {
                        id,
                        state,
                        deadline: Box::pin(tokio::time::sleep(self.budget.limits.deadline)),
                        head_read: 0,
                        head: [0; HEAD],
                        left: 0,
                    })
                }
            };
            let mut taken = 0;
            if current.head_read < HEAD {
                let n = (HEAD - current.head_read).min(data.len());
                current.head[current.head_read..current.head_read + n].copy_from_slice(&data[..n]);
                current.head_read += n;
                taken += n;
                if current.head_read == HEAD {
                    let h = current.head;
                    current.left = u32::from_be_bytes([h[1], h[2], h[3], h[4]]) as usize;
                }
            }
            if current.head_read == HEAD {
                let n = current.left.min(data.len() - taken);
                current.left -= n;
                taken += n;
            }
            data = &data[taken..];
            if current.head_read == HEAD && current.left == 0 {
                let id = current.id;
                self.current = None;
                self.budget.release(id);
            } else if !self.budget.charge(current.id, taken) {
                return Err(());
            }
        }
        Ok(())
    }

    /// The request's failure: counted and logged when it is the deadline (the budget counts
    /// its own endings).
    fn fail(&mut self, past_deadline: bool) -> Status {
        self.failed = true;
        if let Some(c) = self.current.take() {
            self.budget.release(c.id);
        }
        if past_deadline {
            let why = format!(
                "a request message not complete within [service] message_deadline_ms ({} ms)",
                self.budget.limits.deadline.as_millis()
            );
            let peer = self
                .info
                .as_ref()
                .map_or_else(|| "an unknown peer".to_owned(), |p| p.peer().to_string());
            self.budget.stats.refuse(
                Cause::MessageDeadline,
                &peer,
                &format_args!("{why}; its request ends"),
            );
            Status::deadline_exceeded(why)
        } else {
            Status::resource_exhausted(
                "the request's message was ended unfinished to keep the bytes of incomplete \
                 messages under the learner's budget ([service] max_incomplete_bytes, \
                 max_incomplete_bytes_per_connection); send it again",
            )
        }
    }
}

impl HttpBody for BudgetedBody {
    type Data = Bytes;
    type Error = Status;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Status>>> {
        let this = &mut *self;
        if this.failed {
            return Poll::Ready(None);
        }
        if let Some(c) = &mut this.current {
            *c.state.reader.lock().expect("message waker") = Some(cx.waker().clone());
            if c.state.ended.load(Ordering::Acquire) {
                return Poll::Ready(Some(Err(this.fail(false))));
            }
            if c.deadline.as_mut().poll(cx).is_ready() {
                return Poll::Ready(Some(Err(this.fail(true))));
            }
        }
        let frame = match Pin::new(&mut this.inner).poll_frame(cx) {
            Poll::Ready(Some(Ok(frame))) => frame,
            other => return other,
        };
        if let Some(data) = frame.data_ref() {
            if this.account(data).is_err() {
                return Poll::Ready(Some(Err(this.fail(false))));
            }
            // A message that began in this frame: its deadline's timer must know the task.
            if let Some(c) = &mut this.current {
                *c.state.reader.lock().expect("message waker") = Some(cx.waker().clone());
                let _ = c.deadline.as_mut().poll(cx);
            }
        }
        Poll::Ready(Some(Ok(frame)))
    }

    fn is_end_stream(&self) -> bool {
        self.failed || self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

impl Drop for BudgetedBody {
    fn drop(&mut self) {
        if let Some(c) = self.current.take() {
            self.budget.release(c.id);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use http_body_util::{BodyExt, StreamBody};

    fn budget(total: usize, per_connection: usize) -> Arc<MessageBudget> {
        Arc::new(MessageBudget::new(
            BudgetLimits {
                total,
                per_connection,
                deadline: Duration::from_secs(60),
            },
            Arc::new(ConnectionStats::default()),
        ))
    }

    fn message(len: usize) -> Vec<u8> {
        let mut v = vec![0];
        v.extend_from_slice(&(len as u32).to_be_bytes());
        v.extend(std::iter::repeat_n(7u8, len));
        v
    }

    /// A body of `chunks` followed by a stream that never ends (a peer that stops sending).
    fn stalled(chunks: Vec<Vec<u8>>, budget: &Arc<MessageBudget>) -> BudgetedBody {
        let frames = tokio_stream::iter(
            chunks
                .into_iter()
                .map(|c| Ok::<_, Status>(Frame::data(Bytes::from(c)))),
        );
        let body = StreamBody::new(tokio_stream::StreamExt::chain(frames, tokio_stream::pending()));
        BudgetedBody::new(Body::new(body), budget.clone(), None)
    }

    /// Reads every frame `body` has ready; the error it failed with, if any.
    async fn drain(body: &mut BudgetedBody) -> Option<Status> {
        loop {
            match tokio::time::timeout(Duration::from_millis(20), body.frame()).await {
                Ok(Some(Ok(_))) => continue,
                Ok(Some(Err(e))) => return Some(e),
                Ok(None) | Err(_) => return None,
            }
        }
    }

    #[tokio::test]
    async fn complete_messages_hold_nothing_and_split_heads_are_followed() {
        let b = budget(100, 100);
        let mut two = message(30);
        two.extend(message(40));
        // Split inside the second message's head and body.
        let (a, rest) = two.split_at(37);
        let (c, d) = rest.split_at(10);
        let mut body = stalled(vec![a.to_vec(), c.to_vec(), d.to_vec()], &b);
        assert!(drain(&mut body).await.is_none());
        assert_eq!(b.held(), 0);
        // Half a message holds its bytes until it completes or the body is dropped.
        let half = message(80)[..50].to_vec();
        let mut body = stalled(vec![half], &b);
        assert!(drain(&mut body).await.is_none());
        assert_eq!(b.held(), 50);
        drop(body);
        assert_eq!(b.held(), 0);
    }

    #[tokio::test]
    async fn the_oldest_incomplete_message_ends_to_make_room() {
        let b = budget(100, 1000);
        let mut old = stalled(vec![message(80)[..60].to_vec()], &b);
        assert!(drain(&mut old).await.is_none());
        // A newer message over the total ends the older one, which fails when read next.
        let mut new = stalled(vec![message(80)[..60].to_vec()], &b);
        assert!(drain(&mut new).await.is_none());
        assert_eq!(b.held(), 60);
        let e = drain(&mut old).await.expect("the older message ends");
        assert_eq!(e.code(), tonic::Code::ResourceExhausted);
        assert_eq!(b.stats.snapshot().messages_ended_for_room, 1);
        // The newer completes.
        let rest = message(80)[60..].to_vec();
        let mut done = stalled(vec![message(80)[..60].to_vec(), rest], &b);
        assert!(drain(&mut done).await.is_none());
        // A message alone over the cap ends itself.
        let big = budget(10, 1000);
        let mut alone = stalled(vec![message(80)[..60].to_vec()], &big);
        assert_eq!(
            drain(&mut alone).await.unwrap().code(),
            tonic::Code::ResourceExhausted
        );
        assert_eq!(big.held(), 0);
    }

    #[tokio::test]
    async fn a_message_past_its_deadline_ends_its_request() {
        let b = Arc::new(MessageBudget::new(
            BudgetLimits {
                total: 1000,
                per_connection: 1000,
                deadline: Duration::from_millis(50),
            },
            Arc::new(ConnectionStats::default()),
        ));
        let mut body = stalled(vec![message(80)[..10].to_vec()], &b);
        assert!(body.frame().await.unwrap().is_ok());
        // A watchdog, not a timing assertion: the deadline's timer wakes the reader.
        let e = tokio::time::timeout(Duration::from_secs(60), body.frame())
            .await
            .expect("watchdog: the deadline never ended the request")
            .unwrap()
            .unwrap_err();
        assert_eq!(e.code(), tonic::Code::DeadlineExceeded);
        assert!(e.message().contains("message_deadline_ms"), "{e}");
        assert_eq!(b.held(), 0);
        assert_eq!(b.stats.snapshot().messages_past_deadline, 1);
    }
}
