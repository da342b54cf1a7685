//! Why a gRPC call was refused, as a domain error: every service returns [`RpcError`] from
//! its handlers and the one `From<RpcError> for tonic::Status` below maps it to a gRPC code;
//! [`TooLargeIsExhausted`] gives a message over a service's limit the same code as the
//! service's own limits (RESOURCE_EXHAUSTED).

/// A refused call; the message is the reason the client reads.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RpcError {
    /// The request breaks the contract (a malformed message, a bad argument).
    #[error("{0}")]
    InvalidArgument(String),
    /// Over a documented limit.
    #[error("{0}")]
    ResourceExhausted(String),
    /// The service cannot answer now (shutting down, nothing to answer with yet).
    #[error("{0}")]
    Unavailable(String),
    /// The request does not fit the service's state (an evaluation nobody asked for).
    #[error("{0}")]
    FailedPrecondition(String),
    /// The caller may not do this (an evaluation report from an actor that was not asked).
    #[error("{0}")]
    PermissionDenied(String),
    /// Somebody else holds what the call names (an actor id another connection holds).
    #[error("{0}")]
    AlreadyExists(String),
    /// The service failed (a write to disk).
    #[error("{0}")]
    Internal(String),
    /// The client cancelled the call.
    #[error("{0}")]
    Cancelled(String),
}

impl RpcError {
    /// The service is stopping.
    pub fn shutting_down(service: &str) -> Self {
        Self::Unavailable(format!("the {service} is shutting down"))
    }
}

impl From<RpcError> for tonic::Status {
    fn from(e: RpcError) -> Self {
        match e {
            RpcError::InvalidArgument(m) => Self::invalid_argument(m),
            RpcError::ResourceExhausted(m) => Self::resource_exhausted(m),
            RpcError::Unavailable(m) => Self::unavailable(m),
            RpcError::FailedPrecondition(m) => Self::failed_precondition(m),
            RpcError::PermissionDenied(m) => Self::permission_denied(m),
            RpcError::AlreadyExists(m) => Self::already_exists(m),
            RpcError::Internal(m) => Self::internal(m),
            RpcError::Cancelled(m) => Self::cancelled(m),
        }
    }
}

/// A service whose answer to a request message over its decoding limit is RESOURCE_EXHAUSTED,
/// the code gRPC gives for a message larger than allowed (tonic itself answers OUT_OF_RANGE).
/// The answer is rewritten where tonic gives it before the handler runs (a unary request),
/// from the status in the response's headers; everything else passes untouched.
#[derive(Debug, Clone)]
pub struct TooLargeIsExhausted<S>(pub S);

impl<S: tonic::server::NamedService> tonic::server::NamedService for TooLargeIsExhausted<S> {
    const NAME: &'static str = S::NAME;
}

impl<S> tonic::codegen::Service<tonic::codegen::http::Request<tonic::body::Body>>
    for TooLargeIsExhausted<S>
where
    S: tonic::codegen::Service<
            tonic::codegen::http::Request<tonic::body::Body>,
            Response = tonic::codegen::http::Response<tonic::body::Body>,
            Error = std::convert::Infallible,
        >,
    S::Future: Send + 'static,
{
    type Response = tonic::codegen::http::Response<tonic::body::Body>;
    type Error = std::convert::Infallible;
    type Future = tonic::codegen::BoxFuture<Self::Response, Self::Error>;

    fn poll_ready(
        &mut self,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Result<(), Self::Error>> {
        self.0.poll_ready(cx)
    }

    fn call(&mut self, request: tonic::codegen::http::Request<tonic::body::Body>) -> Self::Future {
        let answer = self.0.call(request);
        Box::pin(async move {
            let mut response = answer.await?;
            too_large_is_exhausted(response.headers_mut());
            Ok(response)
        })
    }
}

/// Whether tonic's message says a message was over the decoding limit.
fn says_too_large(message: &str) -> bool {
    message.contains("message length too large")
}

/// A receive error of a client stream as the caller should see it: tonic reports a message
/// above the size limit as OUT_OF_RANGE; it is RESOURCE_EXHAUSTED.
pub fn receive_error(status: tonic::Status) -> tonic::Status {
    if status.code() == tonic::Code::OutOfRange && says_too_large(status.message()) {
        RpcError::ResourceExhausted(format!(
            "{} (MAX_MESSAGE_BYTES = {})",
            status.message(),
            crate::MAX_MESSAGE_BYTES
        ))
        .into()
    } else {
        status
    }
}

/// Rewrites tonic's OUT_OF_RANGE for a request message over the limit to RESOURCE_EXHAUSTED.
fn too_large_is_exhausted(headers: &mut tonic::codegen::http::HeaderMap) {
    let out_of_range = headers
        .get("grpc-status")
        .is_some_and(|v| v.as_bytes() == b"11");
    let too_large = headers.get("grpc-message").is_some_and(|v| {
        says_too_large(&String::from_utf8_lossy(v.as_bytes()).replace("%20", " "))
    });
    if out_of_range && too_large {
        headers.insert(
            "grpc-status",
            tonic::codegen::http::HeaderValue::from_static("8"),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_message_over_the_limit_becomes_resource_exhausted() {
        use tonic::codegen::http::{HeaderMap, HeaderValue};
        let headers = |status: &'static str, message: &'static str| {
            let mut h = HeaderMap::new();
            h.insert("grpc-status", HeaderValue::from_static(status));
            h.insert("grpc-message", HeaderValue::from_static(message));
            h
        };
        let mut too_large = headers(
            "11",
            "Error,%20decoded%20message%20length%20too%20large:%20found%205242885%20bytes",
        );
        too_large_is_exhausted(&mut too_large);
        assert_eq!(too_large["grpc-status"], "8");
        let mut other = headers("11", "a%20step%20out%20of%20range");
        too_large_is_exhausted(&mut other);
        assert_eq!(other["grpc-status"], "11");
    }

    #[test]
    fn each_error_keeps_its_reason_under_its_code() {
        let cases = [
            (
                RpcError::InvalidArgument("a".into()),
                tonic::Code::InvalidArgument,
            ),
            (
                RpcError::ResourceExhausted("b".into()),
                tonic::Code::ResourceExhausted,
            ),
            (RpcError::shutting_down("learner"), tonic::Code::Unavailable),
            (
                RpcError::FailedPrecondition("d".into()),
                tonic::Code::FailedPrecondition,
            ),
            (RpcError::Internal("e".into()), tonic::Code::Internal),
            (RpcError::Cancelled("h".into()), tonic::Code::Cancelled),
            (
                RpcError::AlreadyExists("g".into()),
                tonic::Code::AlreadyExists,
            ),
            (
                RpcError::PermissionDenied("f".into()),
                tonic::Code::PermissionDenied,
            ),
        ];
        for (error, code) in cases {
            let reason = error.to_string();
            let status = tonic::Status::from(error);
            assert_eq!((status.code(), status.message()), (code, reason.as_str()));
        }
    }
}
