//! Requests the learner refuses before it decodes them answer the codes gRPC's convention has,
//! and are counted and logged with their peer.
//!
//! tonic refuses a message longer than a service's `max_decoding_message_size` with
//! OUT_OF_RANGE, and a message that does not decode (not protobuf, invalid UTF-8 in a string
//! field, a broken gRPC frame) with INTERNAL, as if the server had failed. The learner's own
//! refusals never use OUT_OF_RANGE (see [`crate::control::refusal_status`]), and its own
//! INTERNAL answers never carry tonic's decoding messages, so [`WireStatus`] rewrites them in
//! the response head (where a refusal before any reply is sent travels, as a trailers-only
//! response): RESOURCE_EXHAUSTED for the size, INVALID_ARGUMENT for the decoding.

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use tonic::server::NamedService;
use tonic::{Code, Status};

use crate::listen::{Cause, ConnectionStats, Peer, PeerInfo};

/// The starts of the messages tonic gives a request it cannot decode (prost's decoding errors,
/// invalid UTF-8 included, and malformed gRPC message frames), all INTERNAL.
const UNDECODABLE: [&str; 3] = [
    "failed to decode Protobuf message",
    "protocol error: received message with",
    "Unexpected EOF decoding stream",
];

/// A gRPC service whose size and decoding refusals answer RESOURCE_EXHAUSTED and
/// INVALID_ARGUMENT (instead of OUT_OF_RANGE and INTERNAL), counted in `stats`.
#[derive(Clone)]
pub struct WireStatus<S> {
    /// The service.
    pub inner: S,
    /// Where the refusals are counted.
    pub stats: Arc<ConnectionStats>,
}

impl<S: NamedService> NamedService for WireStatus<S> {
    const NAME: &'static str = S::NAME;
}

/// The refusal `response`'s head carries, if it is one of tonic's size or decoding refusals:
/// its new status and what is counted.
fn refusal(headers: &http::HeaderMap) -> Option<(Status, Cause)> {
    let status = Status::from_header_map(headers)?;
    match status.code() {
        Code::OutOfRange => Some((Status::resource_exhausted(status.message()), Cause::Oversized)),
        Code::Internal if UNDECODABLE.iter().any(|s| status.message().starts_with(s)) => Some((
            Status::invalid_argument(format!("the request does not decode: {}", status.message())),
            Cause::Undecodable,
        )),
        _ => None,
    }
}

/// Rewrites a size or decoding refusal in `response`'s head; counts and logs it with `peer`.
fn remap<B>(
    mut response: http::Response<B>,
    peer: Option<Peer>,
    stats: &ConnectionStats,
) -> http::Response<B> {
    let Some((status, cause)) = refusal(response.headers()) else {
        return response;
    };
    let peer = peer.map_or_else(|| "an unknown peer".to_owned(), |p| p.to_string());
    stats.refuse(
        cause,
        &peer,
        &format_args!("{:?}: {}", status.code(), status.message()),
    );
    let headers = response.headers_mut();
    headers.remove(Status::GRPC_MESSAGE);
    if let Err(e) = status.add_header(headers) {
        tracing::warn!("cannot rewrite a refusal's status: {e}");
    }
    response
}

type WireFuture<R, E> = Pin<Box<dyn Future<Output = Result<R, E>> + Send>>;

impl<S, B, RB> tower_service::Service<http::Request<B>> for WireStatus<S>
where
    S: tower_service::Service<http::Request<B>, Response = http::Response<RB>>,
    S::Future: Send + 'static,
    RB: 'static,
{
    type Response = http::Response<RB>;
    type Error = S::Error;
    type Future = WireFuture<Self::Response, Self::Error>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, request: http::Request<B>) -> Self::Future {
        let peer = PeerInfo::of(request.extensions()).map(PeerInfo::peer);
        let stats = self.stats.clone();
        let answer = self.inner.call(request);
        Box::pin(async move { answer.await.map(|r| remap(r, peer, &stats)) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn head(status: Status) -> http::Response<()> {
        let mut r = http::Response::new(());
        status.add_header(r.headers_mut()).unwrap();
        r
    }

    fn after(status: Status, stats: &ConnectionStats) -> Status {
        Status::from_header_map(remap(head(status), None, stats).headers()).unwrap()
    }

    #[test]
    fn size_and_decoding_refusals_are_rewritten_and_counted() {
        let stats = ConnectionStats::default();
        let big = after(Status::out_of_range("decoded message length too large"), &stats);
        assert_eq!(big.code(), Code::ResourceExhausted);
        assert_eq!(big.message(), "decoded message length too large");
        let bad = after(
            Status::internal("failed to decode Protobuf message: invalid wire type value: 7"),
            &stats,
        );
        assert_eq!(bad.code(), Code::InvalidArgument);
        assert_eq!(
            bad.message(),
            "the request does not decode: failed to decode Protobuf message: invalid wire type value: 7"
        );
        for unchanged in [
            Status::internal("step intake failed: panicked"),
            Status::invalid_argument("x"),
            Status::ok(""),
        ] {
            let code = unchanged.code();
            assert_eq!(after(unchanged, &stats).code(), code);
        }
        assert!(remap(http::Response::new(()), None, &stats)
            .headers()
            .get("grpc-status")
            .is_none());
        let counted = stats.snapshot();
        assert_eq!((counted.oversized_requests, counted.undecodable_requests), (1, 1));
    }
}
