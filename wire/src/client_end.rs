//! Whether a client stream was ended by its client or cancelled.
//!
//! tonic's server decoder reads a request stream that the client cancelled (RST_STREAM with
//! CANCEL, which is how gRPC clients cancel a call) as the end of the stream: the handler's
//! `message()` returns `Ok(None)` as it does after the client's own end. A handler that acts
//! only on a whole stream (SubmitSessions stores a call's sessions when its stream ends) must
//! tell the two apart. [`WatchesClientEnd`] wraps a served service: each request's body is
//! watched, and a [`ClientEnd`] in the request's extensions says whether the body reached
//! its end (END_STREAM), as it does only when the client ended the stream itself.

use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::task::{Context, Poll};

use tonic::codegen::http;

/// Set when a request's body reached the end its client sent; a cancelled or broken stream
/// never sets it.
#[derive(Debug, Clone, Default)]
pub struct ClientEnd(Arc<AtomicBool>);

impl ClientEnd {
    /// Whether the client ended its stream itself. A request that was not served through
    /// [`WatchesClientEnd`] has no `ClientEnd`: `None`.
    pub fn of<T>(request: &tonic::Request<T>) -> Option<Self> {
        request.extensions().get::<Self>().cloned()
    }

    /// Whether the body's end arrived.
    pub fn ended(&self) -> bool {
        self.0.load(Ordering::Acquire)
    }

    fn mark(&self) {
        self.0.store(true, Ordering::Release);
    }
}

/// A request body that marks its [`ClientEnd`] when it ends.
struct WatchedBody {
    inner: tonic::body::Body,
    end: ClientEnd,
}

impl http_body::Body for WatchedBody {
    type Data = bytes::Bytes;
    type Error = tonic::Status;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Self::Data>, Self::Error>>> {
        let polled = Pin::new(&mut self.inner).poll_frame(cx);
        if let Poll::Ready(None) = polled {
            self.end.mark();
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

/// A service whose requests carry a [`ClientEnd`]; everything else passes untouched.
#[derive(Debug, Clone)]
pub struct WatchesClientEnd<S>(pub S);

impl<S: tonic::server::NamedService> tonic::server::NamedService for WatchesClientEnd<S> {
    const NAME: &'static str = S::NAME;
}

impl<S> tonic::codegen::Service<http::Request<tonic::body::Body>> for WatchesClientEnd<S>
where
    S: tonic::codegen::Service<http::Request<tonic::body::Body>>,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = S::Future;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.0.poll_ready(cx)
    }

    fn call(&mut self, request: http::Request<tonic::body::Body>) -> Self::Future {
        let (mut parts, inner) = request.into_parts();
        let end = ClientEnd::default();
        // a body that is over before it is read (no frames at all) has ended as sent
        if http_body::Body::is_end_stream(&inner) {
            end.mark();
        }
        parts.extensions.insert(end.clone());
        let body = tonic::body::Body::new(WatchedBody { inner, end });
        self.0.call(http::Request::from_parts(parts, body))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use http_body::Body as _;

    fn poll_to_end(body: &mut tonic::body::Body) -> Vec<Result<(), tonic::Code>> {
        let waker = std::task::Waker::noop();
        let mut cx = Context::from_waker(waker);
        let mut seen = Vec::new();
        loop {
            match Pin::new(&mut *body).poll_frame(&mut cx) {
                Poll::Ready(None) => return seen,
                Poll::Ready(Some(frame)) => {
                    let failed = frame.as_ref().err().map(|s| s.code());
                    seen.push(frame.map(|_| ()).map_err(|s| s.code()));
                    if failed.is_some() {
                        return seen;
                    }
                }
                Poll::Pending => panic!("a ready body was pending"),
            }
        }
    }

    /// A body of `frames` data frames that then ends, or fails as a reset stream does.
    struct Frames {
        left: usize,
        then_fail: bool,
    }

    impl http_body::Body for Frames {
        type Data = bytes::Bytes;
        type Error = tonic::Status;

        fn poll_frame(
            mut self: Pin<&mut Self>,
            _: &mut Context<'_>,
        ) -> Poll<Option<Result<http_body::Frame<Self::Data>, Self::Error>>> {
            if self.left > 0 {
                self.left -= 1;
                return Poll::Ready(Some(Ok(http_body::Frame::data(bytes::Bytes::from_static(
                    b"x",
                )))));
            }
            if self.then_fail {
                self.then_fail = false;
                return Poll::Ready(Some(Err(tonic::Status::cancelled("reset"))));
            }
            Poll::Ready(None)
        }
    }

    fn watched(left: usize, then_fail: bool) -> (tonic::body::Body, ClientEnd) {
        let end = ClientEnd::default();
        let inner = tonic::body::Body::new(Frames { left, then_fail });
        let body = tonic::body::Body::new(WatchedBody {
            inner,
            end: end.clone(),
        });
        (body, end)
    }

    #[test]
    fn a_body_that_ends_marks_its_end() {
        let (mut body, end) = watched(2, false);
        assert!(!end.ended());
        assert_eq!(poll_to_end(&mut body), vec![Ok(()), Ok(())]);
        assert!(end.ended());
    }

    #[test]
    fn a_reset_body_never_marks_its_end() {
        let (mut body, end) = watched(2, true);
        let seen = poll_to_end(&mut body);
        assert_eq!(seen.last(), Some(&Err(tonic::Code::Cancelled)));
        assert!(!end.ended(), "a cancelled stream read as ended");
    }
}
