//! Why a gRPC call was refused, as a domain error: every service returns [`RpcError`] from
//! its handlers and the one `From<RpcError> for tonic::Status` below maps it to a gRPC code.

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
    /// The service failed (a write to disk).
    #[error("{0}")]
    Internal(String),
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
            RpcError::Internal(m) => Self::internal(m),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
