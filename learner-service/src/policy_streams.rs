//! `WatchPolicy` without a copy of the policy per stream, and no version held for a reader
//! that does not read.
//!
//! tonic encodes every streamed message into a buffer of its own, so each `WatchPolicy`
//! stream whose client does not read held a private copy of the encoded policy (2.5 MB at the
//! default network size) in the HTTP/2 send queue. Here each published policy is encoded once
//! into a gRPC frame that the learner holds ([`Frames`]); a stream copies it into the HTTP/2
//! send queue in [`PIECE`]-byte pieces as the peer's flow-control window lets it, holding
//! only a weak reference to the version it is sending. A reader that never reads holds a piece
//! or two in the send queue, not a version: the learner keeps the newest version, and a
//! superseded one for `[service] policy_send_grace_ms` (at most [`SUPERSEDED_KEPT`] of them) so
//! that a stream in the middle of it can finish; a stream that has not finished by then ends
//! (counted and logged) and its actor opens a new one. Streams are capped in total, per source
//! address (TCP) and per registration, and each one is authenticated with its actor's
//! credential. A registration's stream beyond its cap ends its oldest one instead of being
//! refused (an actor that reconnects is never locked out by its own stale stream), so one
//! token holder can take at most its address's share of the streams, never every slot. Every
//! refusal and replacement is counted in `status.json` (`connections`) and logged with the
//! peer (the first 20 of each cause, then every 1000th).
//!
//! [`DataRoutes`] is the `adp.v1.Data` service: `WatchPolicy` is answered here, every other
//! method by the generated server.

use std::collections::{HashMap, VecDeque};
use std::convert::Infallible;
use std::future::Future;
use std::net::IpAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex, Weak};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use http_body::{Body as HttpBody, Frame};
use http_body_util::{BodyExt, Limited};
use prost::bytes::{BufMut, Bytes, BytesMut};
use prost::Message;
use proto::pb;
use tokio::sync::{oneshot, watch, OwnedSemaphorePermit, Semaphore};
use tokio_stream::StreamExt;
use tonic::body::Body;
use tonic::server::NamedService;
use tonic::Status;

use crate::control::refusal_status;
use crate::data::DataService;
use crate::listen::{Cause, Peer, PeerInfo};
use crate::shared::Shared;

/// The HTTP/2 path of `WatchPolicy`.
const WATCH_PATH: &str = "/adp.v1.Data/WatchPolicy";

/// Bytes of a policy frame a stream copies into the HTTP/2 send queue at a time (HTTP/2's
/// default frame size).
const PIECE: usize = 16 * 1024;

/// Superseded policy versions kept for the streams still sending them.
const SUPERSEDED_KEPT: usize = 2;

/// The encoded frames of the newest policy and of the versions it superseded lately.
#[derive(Default)]
struct Frames {
    /// The newest snapshot encoded and its gRPC frame.
    newest: Option<(Arc<pb::PolicySnapshot>, Arc<Bytes>)>,
    /// Superseded frames, oldest first, each with when it was superseded.
    superseded: VecDeque<(Arc<Bytes>, Instant)>,
}

impl Frames {
    /// Drops the superseded frames older than `grace` (and beyond [`SUPERSEDED_KEPT`]).
    fn prune(&mut self, grace: Duration) {
        while self.superseded.len() > SUPERSEDED_KEPT
            || self
                .superseded
                .front()
                .is_some_and(|(_, at)| at.elapsed() >= grace)
        {
            self.superseded.pop_front();
        }
    }
}

/// The open `WatchPolicy` streams and the newest policy's encoded frame they share.
pub struct PolicyStreams {
    shared: Arc<Shared>,
    policy: watch::Receiver<Arc<pb::PolicySnapshot>>,
    /// One permit per open stream (`[service] max_policy_streams`).
    total: Arc<Semaphore>,
    /// `[service] max_policy_streams`, for the refusal message.
    max_total: u32,
    /// `[service] policy_streams_per_actor`.
    per_actor: u32,
    /// `[service] policy_streams_per_ip`.
    per_address: u32,
    /// Open streams per actor and per source address.
    open: Arc<Mutex<StreamTable>>,
    /// The frames streams send from.
    frames: Mutex<Frames>,
    /// `[service] policy_send_grace_ms`.
    grace: Duration,
}

/// The open streams per actor (oldest first, each with its id and the sender that ends it)
/// and per TCP source address.
#[derive(Default)]
struct StreamTable {
    by_actor: HashMap<u64, VecDeque<(u64, oneshot::Sender<()>)>>,
    by_address: HashMap<IpAddr, u32>,
    next_id: u64,
}

/// One open stream's place in the caps, given back when the stream is dropped.
struct StreamSlot {
    open: Arc<Mutex<StreamTable>>,
    actor: u64,
    id: u64,
    address: Option<IpAddr>,
    _permit: OwnedSemaphorePermit,
}

impl Drop for StreamSlot {
    fn drop(&mut self) {
        let mut open = self.open.lock().expect("policy stream table");
        if let Some(streams) = open.by_actor.get_mut(&self.actor) {
            streams.retain(|(id, _)| *id != self.id);
            if streams.is_empty() {
                open.by_actor.remove(&self.actor);
            }
        }
        if let Some(address) = self.address {
            if let Some(n) = open.by_address.get_mut(&address) {
                *n -= 1;
                if *n == 0 {
                    open.by_address.remove(&address);
                }
            }
        }
    }
}

impl PolicyStreams {
    /// Streams of the policies published on `policy`, at most `max_total` at once,
    /// `per_address` from one TCP source address and `per_actor` per registration (one more
    /// ends the registration's oldest); a superseded version is kept `grace` for the streams
    /// still sending it.
    pub fn new(
        shared: Arc<Shared>,
        policy: watch::Receiver<Arc<pb::PolicySnapshot>>,
        max_total: u32,
        per_address: u32,
        per_actor: u32,
        grace: Duration,
    ) -> Self {
        Self {
            shared,
            policy,
            total: Arc::new(Semaphore::new(max_total as usize)),
            max_total,
            per_actor: per_actor.max(1),
            per_address,
            open: Arc::new(Mutex::new(StreamTable::default())),
            frames: Mutex::new(Frames::default()),
            grace,
        }
    }

    /// The gRPC frame (compression flag, length, message) of `snapshot`, encoded once per
    /// published snapshot and held by the learner while it is the newest (and `grace` after);
    /// streams hold a weak reference.
    fn frame(&self, snapshot: &Arc<pb::PolicySnapshot>) -> Weak<Bytes> {
        let mut frames = self.frames.lock().expect("policy frames");
        frames.prune(self.grace);
        if let Some((s, frame)) = &frames.newest {
            if Arc::ptr_eq(s, snapshot) {
                return Arc::downgrade(frame);
            }
        }
        let len = snapshot.encoded_len();
        let mut buf = BytesMut::with_capacity(5 + len);
        buf.put_u8(0);
        buf.put_u32(len as u32);
        snapshot
            .encode(&mut buf)
            .expect("the buffer has the message's length");
        let frame = Arc::new(buf.freeze());
        let weak = Arc::downgrade(&frame);
        if let Some((_, older)) = frames.newest.replace((snapshot.clone(), frame)) {
            frames.superseded.push_back((older, Instant::now()));
            frames.prune(self.grace);
        }
        weak
    }

    /// Drops the superseded frames past their grace.
    fn prune(&self) {
        self.frames.lock().expect("policy frames").prune(self.grace);
    }

    /// Takes a place for a stream of `actor` from `peer`, ending the actor's oldest stream when
    /// it has `per_actor` open, or refuses it (counted and logged) when the address's or the
    /// learner's cap is reached. Returns the place and the receiver that ends the stream when
    /// a newer one of the actor replaces it.
    fn take_slot(
        &self,
        actor: u64,
        peer: Option<Peer>,
    ) -> Result<(StreamSlot, oneshot::Receiver<()>), Status> {
        let stats = &self.shared.connections;
        let shown: &dyn std::fmt::Display = match &peer {
            Some(p) => p,
            None => &"an unknown peer",
        };
        let address = match peer {
            Some(Peer::Tcp(addr)) => Some(addr.ip()),
            _ => None,
        };
        let mut open = self.open.lock().expect("policy stream table");
        if let Some(ip) = address {
            let n = open.by_address.get(&ip).copied().unwrap_or(0);
            if n >= self.per_address {
                let why = format!(
                    "{ip} already has {n} WatchPolicy streams open ([service] policy_streams_per_ip)"
                );
                stats.refuse(Cause::PolicyStreamsPerAddress, shown, &why);
                return Err(Status::resource_exhausted(why));
            }
        }
        let permit = self.total.clone().try_acquire_owned().map_err(|_| {
            let why = format!(
                "{} WatchPolicy streams are open, the most the learner serves ([service] \
                 max_policy_streams)",
                self.max_total
            );
            stats.refuse(Cause::PolicyStreamsFull, shown, &why);
            Status::resource_exhausted(why)
        })?;
        let id = open.next_id;
        open.next_id += 1;
        let (end, ended) = oneshot::channel();
        let streams = open.by_actor.entry(actor).or_default();
        while streams.len() >= self.per_actor as usize {
            let Some((_, older)) = streams.pop_front() else {
                break;
            };
            // The older stream ends (with an OK status) and gives its place back when dropped.
            let _ = older.send(());
            stats.refuse(
                Cause::PolicyStreamReplaced,
                shown,
                &format!("actor {actor} opened another WatchPolicy stream: its older one ends"),
            );
        }
        streams.push_back((id, end));
        if let Some(ip) = address {
            *open.by_address.entry(ip).or_default() += 1;
        }
        Ok((
            StreamSlot {
                open: self.open.clone(),
                actor,
                id,
                address,
                _permit: permit,
            },
            ended,
        ))
    }

    /// Reads the request, checks run, credential and caps, and opens the stream.
    async fn open_stream(self: Arc<Self>, request: http::Request<Body>) -> Result<Body, Status> {
        let (parts, body) = request.into_parts();
        let raw = Limited::new(body, proto::grpc::MAX_CONTROL_REQUEST_BYTES)
            .collect()
            .await
            .map_err(|e| Status::resource_exhausted(format!("WatchPolicy request: {e}")))?
            .to_bytes();
        let r = decode_request(&raw)?;
        let run = r.run.clone().unwrap_or_default();
        let checked = self
            .shared
            .validator
            .check_run(&run.run_id, run.incarnation)
            .and_then(|()| self.shared.authenticate(r.actor_id, &r.actor_secret));
        if let Err(why) = checked {
            let _actor = tracing::info_span!("actor", actor_id = r.actor_id).entered();
            self.shared.refuse(&why, 1);
            return Err(refusal_status(&why));
        }
        let peer = PeerInfo::of(&parts.extensions).map(PeerInfo::peer);
        let (slot, replaced) = self.take_slot(r.actor_id, peer)?;
        let have = r.have_version;
        // The channel starts with an empty placeholder until the first policy is published:
        // never send it (an actor would take it for a policy without weights). A reader that
        // falls behind gets the newest version only (the watch channel keeps one).
        let versions = tokio_stream::wrappers::WatchStream::new(self.policy.clone())
            .filter(move |p| !p.weights.is_empty() && (p.version > have || have == 0));
        Ok(Body::new(PolicyBody {
            streams: self,
            versions: Box::pin(versions),
            replaced,
            sending: None,
            ended: false,
            peer,
            _slot: slot,
        }))
    }
}

/// The version a [`PolicyBody`] is sending: a weak reference to its frame and how far it got.
struct Sending {
    version: u64,
    frame: Weak<Bytes>,
    sent: usize,
}

/// A `WatchPolicy` response body: each new version's frame, copied in [`PIECE`]-byte pieces,
/// then (when the policies end, i.e. the learner stops) trailers saying OK. It ends when a
/// newer stream of its actor replaced it (between versions), and fails (the stream is reset)
/// when the frame it is in the middle of was dropped: superseded longer than the grace.
struct PolicyBody {
    streams: Arc<PolicyStreams>,
    versions: Pin<Box<dyn tokio_stream::Stream<Item = Arc<pb::PolicySnapshot>> + Send>>,
    replaced: oneshot::Receiver<()>,
    sending: Option<Sending>,
    ended: bool,
    peer: Option<Peer>,
    _slot: StreamSlot,
}

impl PolicyBody {
    /// The trailers of a stream that ends well.
    fn trailers() -> Frame<Bytes> {
        let mut trailers = http::HeaderMap::new();
        trailers.insert("grpc-status", http::HeaderValue::from_static("0"));
        Frame::trailers(trailers)
    }
}

impl HttpBody for PolicyBody {
    type Data = Bytes;
    type Error = Status;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Status>>> {
        let this = &mut *self;
        if this.ended {
            return Poll::Ready(None);
        }
        loop {
            if let Some(s) = &mut this.sending {
                let Some(frame) = s.frame.upgrade() else {
                    let version = s.version;
                    this.ended = true;
                    this.sending = None;
                    let why = format!(
                        "its WatchPolicy stream had not sent policy version {version} within \
                         [service] policy_send_grace_ms ({} ms) of a newer one; the stream ends",
                        this.streams.grace.as_millis()
                    );
                    let shown: &dyn std::fmt::Display = match &this.peer {
                        Some(p) => p,
                        None => &"an unknown peer",
                    };
                    this.streams
                        .shared
                        .connections
                        .refuse(Cause::PolicyStreamUnfinished, shown, &why);
                    return Poll::Ready(Some(Err(Status::resource_exhausted(why))));
                };
                let end = (s.sent + PIECE).min(frame.len());
                let piece = Bytes::copy_from_slice(&frame[s.sent..end]);
                s.sent = end;
                if end == frame.len() {
                    this.sending = None;
                }
                return Poll::Ready(Some(Ok(Frame::data(piece))));
            }
            if Pin::new(&mut this.replaced).poll(cx).is_ready() {
                this.ended = true;
                return Poll::Ready(Some(Ok(Self::trailers())));
            }
            match this.versions.as_mut().poll_next(cx) {
                Poll::Ready(Some(p)) => {
                    this.sending = Some(Sending {
                        version: p.version,
                        frame: this.streams.frame(&p),
                        sent: 0,
                    });
                }
                Poll::Ready(None) => {
                    this.ended = true;
                    return Poll::Ready(Some(Ok(Self::trailers())));
                }
                Poll::Pending => {
                    this.streams.prune();
                    return Poll::Pending;
                }
            }
        }
    }
}

/// Decodes a unary gRPC request body (one uncompressed frame) into a `PolicyRequest`.
fn decode_request(raw: &[u8]) -> Result<pb::PolicyRequest, Status> {
    let bad = |why: &str| Status::invalid_argument(format!("WatchPolicy request: {why}"));
    if raw.len() < 5 {
        return Err(bad("shorter than a gRPC frame header"));
    }
    if raw[0] != 0 {
        return Err(Status::unimplemented(
            "WatchPolicy request: compressed messages are not accepted",
        ));
    }
    let len = u32::from_be_bytes([raw[1], raw[2], raw[3], raw[4]]) as usize;
    if raw.len() != 5 + len {
        return Err(bad("the frame length does not match the body"));
    }
    pb::PolicyRequest::decode(&raw[5..]).map_err(|e| bad(&e.to_string()))
}

/// The `adp.v1.Data` service: `WatchPolicy` from [`PolicyStreams`], the rest from the
/// generated server.
#[derive(Clone)]
pub struct DataRoutes {
    /// The generated server (`PushSteps`).
    pub inner: pb::data_server::DataServer<DataService>,
    /// `WatchPolicy`.
    pub streams: Arc<PolicyStreams>,
}

impl NamedService for DataRoutes {
    const NAME: &'static str = <pb::data_server::DataServer<DataService> as NamedService>::NAME;
}

type RouteFuture = Pin<Box<dyn Future<Output = Result<http::Response<Body>, Infallible>> + Send>>;

impl tower_service::Service<http::Request<Body>> for DataRoutes {
    type Response = http::Response<Body>;
    type Error = Infallible;
    type Future = RouteFuture;

    fn poll_ready(&mut self, _cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, request: http::Request<Body>) -> Self::Future {
        if request.uri().path() == WATCH_PATH {
            let streams = self.streams.clone();
            Box::pin(async move {
                Ok(match streams.open_stream(request).await {
                    Ok(body) => {
                        let mut response = http::Response::new(body);
                        response.headers_mut().insert(
                            http::header::CONTENT_TYPE,
                            http::HeaderValue::from_static("application/grpc"),
                        );
                        response
                    }
                    Err(status) => status.into_http(),
                })
            })
        } else {
            let mut inner = self.inner.clone();
            Box::pin(async move { tower_service::Service::call(&mut inner, request).await })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixture::{fixture, td3_config};

    #[test]
    fn a_registration_keeps_one_stream_and_an_address_its_share() {
        let f = fixture(td3_config(), 60_000);
        let (_tx, rx) = watch::channel(Arc::new(pb::PolicySnapshot::default()));
        let streams = PolicyStreams::new(f.shared.clone(), rx, 4, 2, 1, Duration::from_secs(10));
        let one: Peer = Peer::Tcp("127.0.0.1:5000".parse().unwrap());
        let two: Peer = Peer::Tcp("127.0.0.2:5000".parse().unwrap());
        // A second stream of actor 7 ends its first (which gives its place back when dropped).
        let (first, mut first_ended) = streams.take_slot(7, Some(one)).unwrap();
        let (second, mut second_ended) = streams.take_slot(7, Some(one)).unwrap();
        assert!(first_ended.try_recv().is_ok(), "the older stream is told to end");
        assert!(second_ended.try_recv().is_err());
        drop(first);
        // Address 127.0.0.1 holds 1 of its 2; another actor there takes the second, a third
        // is refused; 127.0.0.2 and the Unix socket are served.
        let _b = streams.take_slot(8, Some(one)).unwrap();
        let Err(refused) = streams.take_slot(9, Some(one)) else {
            panic!("a third stream from 127.0.0.1 was served");
        };
        assert_eq!(refused.code(), tonic::Code::ResourceExhausted);
        assert!(refused.message().contains("policy_streams_per_ip"), "{refused}");
        let _c = streams.take_slot(9, Some(two)).unwrap();
        let _d = streams.take_slot(10, Some(Peer::Unix)).unwrap();
        // Four open: the learner's cap.
        let Err(full) = streams.take_slot(11, Some(two)) else {
            panic!("a fifth stream was served");
        };
        assert!(full.message().contains("max_policy_streams"), "{full}");
        drop(second);
        let _e = streams.take_slot(11, Some(one)).unwrap();
        let c = f.shared.connections.snapshot();
        assert_eq!(
            (
                c.policy_streams_replaced,
                c.policy_streams_refused_per_address,
                c.policy_streams_refused
            ),
            (1, 1, 1)
        );
    }

    #[test]
    fn requests_are_single_uncompressed_frames() {
        let msg = pb::PolicyRequest {
            actor_id: 3,
            have_version: 2,
            ..Default::default()
        };
        let mut raw = vec![0u8];
        raw.extend((msg.encoded_len() as u32).to_be_bytes());
        raw.extend(msg.encode_to_vec());
        assert_eq!(decode_request(&raw).unwrap(), msg);
        assert_eq!(
            decode_request(&raw[..3]).unwrap_err().code(),
            tonic::Code::InvalidArgument
        );
        assert_eq!(
            decode_request(&raw[..raw.len() - 1]).unwrap_err().code(),
            tonic::Code::InvalidArgument
        );
        raw[0] = 1;
        assert_eq!(
            decode_request(&raw).unwrap_err().code(),
            tonic::Code::Unimplemented
        );
    }
}
