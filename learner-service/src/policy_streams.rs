//! `WatchPolicy` without a copy of the policy per stream.
//!
//! tonic encodes every streamed message into a buffer of its own, so each `WatchPolicy`
//! stream whose client does not read held a private copy of the encoded policy (2.5 MB at the
//! default network size) in the HTTP/2 send queue. Here the newest policy is encoded once into
//! a gRPC frame ([`Bytes`], reference-counted) and every stream sends that same frame; an
//! unread stream holds a reference, not a copy. Streams are capped in total and per actor, and
//! each one is authenticated with its actor's credential.
//!
//! [`DataRoutes`] is the `adp.v1.Data` service: `WatchPolicy` is answered here, every other
//! method by the generated server.

use std::collections::HashMap;
use std::convert::Infallible;
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use http_body::Frame;
use http_body_util::{BodyExt, Limited, StreamBody};
use prost::bytes::{BufMut, Bytes, BytesMut};
use prost::Message;
use proto::pb;
use tokio::sync::{watch, OwnedSemaphorePermit, Semaphore};
use tokio_stream::StreamExt;
use tonic::body::Body;
use tonic::server::NamedService;
use tonic::Status;

use crate::control::refusal_status;
use crate::data::DataService;
use crate::shared::Shared;

/// The HTTP/2 path of `WatchPolicy`.
const WATCH_PATH: &str = "/adp.v1.Data/WatchPolicy";

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
    /// Open streams per actor id.
    open: Arc<Mutex<HashMap<u64, u32>>>,
    /// The snapshot encoded last and its gRPC frame.
    frame: Mutex<Option<(Arc<pb::PolicySnapshot>, Bytes)>>,
}

/// One open stream's place in the caps, given back when the stream is dropped.
struct StreamSlot {
    open: Arc<Mutex<HashMap<u64, u32>>>,
    actor: u64,
    _permit: OwnedSemaphorePermit,
}

impl Drop for StreamSlot {
    fn drop(&mut self) {
        let mut open = self.open.lock().expect("policy stream table");
        if let Some(n) = open.get_mut(&self.actor) {
            *n -= 1;
            if *n == 0 {
                open.remove(&self.actor);
            }
        }
    }
}

impl PolicyStreams {
    /// Streams of the policies published on `policy`, at most `max_total` at once and
    /// `per_actor` per actor.
    pub fn new(
        shared: Arc<Shared>,
        policy: watch::Receiver<Arc<pb::PolicySnapshot>>,
        max_total: u32,
        per_actor: u32,
    ) -> Self {
        Self {
            shared,
            policy,
            total: Arc::new(Semaphore::new(max_total as usize)),
            max_total,
            per_actor,
            open: Arc::new(Mutex::new(HashMap::new())),
            frame: Mutex::new(None),
        }
    }

    /// The gRPC frame (compression flag, length, message) of `snapshot`, encoded once per
    /// published snapshot and shared by every stream.
    fn frame(&self, snapshot: &Arc<pb::PolicySnapshot>) -> Bytes {
        let mut cached = self.frame.lock().expect("policy frame");
        if let Some((s, frame)) = cached.as_ref() {
            if Arc::ptr_eq(s, snapshot) {
                return frame.clone();
            }
        }
        let len = snapshot.encoded_len();
        let mut buf = BytesMut::with_capacity(5 + len);
        buf.put_u8(0);
        buf.put_u32(len as u32);
        snapshot
            .encode(&mut buf)
            .expect("the buffer has the message's length");
        let frame = buf.freeze();
        *cached = Some((snapshot.clone(), frame.clone()));
        frame
    }

    /// Takes a place for a stream of `actor`, or says which cap is reached.
    fn take_slot(&self, actor: u64) -> Result<StreamSlot, Status> {
        let mut open = self.open.lock().expect("policy stream table");
        let n = open.entry(actor).or_default();
        if *n >= self.per_actor {
            return Err(Status::resource_exhausted(format!(
                "actor {actor} already has {n} WatchPolicy streams open ([service] \
                 policy_streams_per_actor = {})",
                self.per_actor
            )));
        }
        let permit = self.total.clone().try_acquire_owned().map_err(|_| {
            Status::resource_exhausted(format!(
                "{} WatchPolicy streams are open, the most the learner serves ([service] \
                 max_policy_streams)",
                self.max_total
            ))
        })?;
        *n += 1;
        Ok(StreamSlot {
            open: self.open.clone(),
            actor,
            _permit: permit,
        })
    }

    /// Reads the request, checks run, credential and caps, and opens the stream.
    async fn open_stream(self: Arc<Self>, request: http::Request<Body>) -> Result<Body, Status> {
        let raw = Limited::new(request.into_body(), proto::grpc::MAX_CONTROL_REQUEST_BYTES)
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
        let slot = self.take_slot(r.actor_id)?;
        let have = r.have_version;
        let streams = self.clone();
        // The channel starts with an empty placeholder until the first policy is published:
        // never send it (an actor would take it for a policy without weights). A reader that
        // falls behind gets the newest version only (the watch channel keeps one).
        let frames = tokio_stream::wrappers::WatchStream::new(self.policy.clone())
            .filter(move |p| !p.weights.is_empty() && (p.version > have || have == 0))
            .map(move |p| {
                let _open = &slot;
                Ok::<_, Infallible>(Frame::data(streams.frame(&p)))
            });
        // When the policies end (the learner stops), the stream ends as a gRPC stream does: with
        // trailers saying OK.
        let mut trailers = http::HeaderMap::new();
        trailers.insert("grpc-status", http::HeaderValue::from_static("0"));
        let end = tokio_stream::once(Ok(Frame::trailers(trailers)));
        Ok(Body::new(StreamBody::new(frames.chain(end))))
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
