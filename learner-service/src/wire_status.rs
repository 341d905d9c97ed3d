//! Oversized requests answer RESOURCE_EXHAUSTED, as gRPC's convention has it.
//!
//! tonic refuses a message longer than a service's `max_decoding_message_size` with
//! OUT_OF_RANGE. The learner's own refusals never use that code (see
//! [`crate::control::refusal_status`]), so [`SizeStatus`] rewrites it in the response head
//! (where a refusal before any reply is sent travels, as a trailers-only response).

use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll};

use tonic::server::NamedService;

/// `grpc-status` of OUT_OF_RANGE.
const OUT_OF_RANGE: &str = "11";
/// `grpc-status` of RESOURCE_EXHAUSTED.
const RESOURCE_EXHAUSTED: &str = "8";

/// A gRPC service whose size refusals answer RESOURCE_EXHAUSTED instead of OUT_OF_RANGE.
#[derive(Clone)]
pub struct SizeStatus<S>(pub S);

impl<S: NamedService> NamedService for SizeStatus<S> {
    const NAME: &'static str = S::NAME;
}

/// Rewrites an OUT_OF_RANGE status in `response`'s head.
fn remap<B>(mut response: http::Response<B>) -> http::Response<B> {
    let headers = response.headers_mut();
    if headers.get("grpc-status").is_some_and(|v| v == OUT_OF_RANGE) {
        headers.insert("grpc-status", http::HeaderValue::from_static(RESOURCE_EXHAUSTED));
    }
    response
}

type SizeFuture<R, E> = Pin<Box<dyn Future<Output = Result<R, E>> + Send>>;

impl<S, Req, B> tower_service::Service<Req> for SizeStatus<S>
where
    S: tower_service::Service<Req, Response = http::Response<B>>,
    S::Future: Send + 'static,
    B: 'static,
{
    type Response = http::Response<B>;
    type Error = S::Error;
    type Future = SizeFuture<Self::Response, Self::Error>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.0.poll_ready(cx)
    }

    fn call(&mut self, request: Req) -> Self::Future {
        let answer = self.0.call(request);
        Box::pin(async move { answer.await.map(remap) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_out_of_range_is_rewritten() {
        let with = |code: &'static str| {
            let mut r = http::Response::new(());
            r.headers_mut()
                .insert("grpc-status", http::HeaderValue::from_static(code));
            remap(r).headers()["grpc-status"].to_str().unwrap().to_owned()
        };
        assert_eq!(with("11"), "8");
        assert_eq!(with("3"), "3");
        assert_eq!(with("0"), "0");
        assert!(remap(http::Response::new(()))
            .headers()
            .get("grpc-status")
            .is_none());
    }
}
