//! The one error type of the client, with the gRPC status code kept wherever the
//! server sent one, so callers (and the conformance checks) can branch on it.
use std::time::Duration;

use tonic::Code;

/// Everything that can go wrong talking to an env server.
#[derive(Debug, thiserror::Error)]
pub enum EnvError {
    /// No connection and handshake succeeded within the retry budget.
    #[error(
        "env server {addr} unreachable after {attempts} attempts over {elapsed:.1?}: {last_error}"
    )]
    Unreachable {
        addr: String,
        attempts: u32,
        elapsed: Duration,
        last_error: String,
    },
    /// The server speaks another major version of the API.
    #[error("API version mismatch with env server {addr}: client speaks {client}; {detail}")]
    VersionMismatch {
        addr: String,
        client: String,
        detail: String,
    },
    /// The server answered a call with a non-OK status.
    #[error("{call} on env server {addr} failed with {}: {}", code_name(.status.code()), .status.message())]
    Rpc {
        addr: String,
        call: &'static str,
        status: tonic::Status,
    },
    /// No answer within the call's deadline.
    #[error("{call} on env server {addr} exceeded its deadline of {deadline:.1?}")]
    Deadline {
        addr: String,
        call: &'static str,
        deadline: Duration,
    },
    /// The Session stream ended or broke while replies were still expected.
    #[error("session stream to env server {addr} closed: {detail}")]
    StreamClosed { addr: String, detail: String },
    /// The server's reply does not follow the API (wrong row counts, bad tensors...).
    #[error("malformed reply from env server {addr}: {detail}")]
    Protocol { addr: String, detail: String },
    /// The caller passed something the API cannot express or the spec rejects.
    #[error("invalid input: {0}")]
    InvalidInput(String),
}

impl EnvError {
    /// The gRPC status code this error corresponds to, where there is one.
    pub fn code(&self) -> Option<Code> {
        match self {
            EnvError::Rpc { status, .. } => Some(status.code()),
            EnvError::Deadline { .. } => Some(Code::DeadlineExceeded),
            EnvError::StreamClosed { .. } | EnvError::Unreachable { .. } => Some(Code::Unavailable),
            EnvError::VersionMismatch { .. } => Some(Code::FailedPrecondition),
            EnvError::InvalidInput(_) => Some(Code::InvalidArgument),
            EnvError::Protocol { .. } => None,
        }
    }

    /// True when the failure means the server (or the connection to it) went away,
    /// so re-connecting and re-making the envs is the way forward. A restarted
    /// server no longer knows old handles, hence NOT_FOUND counts too.
    pub fn is_connection_loss(&self) -> bool {
        match self {
            EnvError::StreamClosed { .. } | EnvError::Deadline { .. } => true,
            EnvError::Rpc { status, .. } => matches!(
                status.code(),
                Code::Unavailable
                    | Code::Unknown
                    | Code::Cancelled
                    | Code::Aborted
                    | Code::DeadlineExceeded
                    | Code::NotFound
            ),
            _ => false,
        }
    }

    pub(crate) fn protocol(addr: &str, detail: impl Into<String>) -> Self {
        EnvError::Protocol {
            addr: addr.to_owned(),
            detail: detail.into(),
        }
    }
}

/// The canonical upper-case name of a status code, as grpc documents it.
pub fn code_name(code: Code) -> &'static str {
    match code {
        Code::Ok => "OK",
        Code::Cancelled => "CANCELLED",
        Code::Unknown => "UNKNOWN",
        Code::InvalidArgument => "INVALID_ARGUMENT",
        Code::DeadlineExceeded => "DEADLINE_EXCEEDED",
        Code::NotFound => "NOT_FOUND",
        Code::AlreadyExists => "ALREADY_EXISTS",
        Code::PermissionDenied => "PERMISSION_DENIED",
        Code::ResourceExhausted => "RESOURCE_EXHAUSTED",
        Code::FailedPrecondition => "FAILED_PRECONDITION",
        Code::Aborted => "ABORTED",
        Code::OutOfRange => "OUT_OF_RANGE",
        Code::Unimplemented => "UNIMPLEMENTED",
        Code::Internal => "INTERNAL",
        Code::Unavailable => "UNAVAILABLE",
        Code::DataLoss => "DATA_LOSS",
        Code::Unauthenticated => "UNAUTHENTICATED",
    }
}

/// Parses a code name as written in `checks.toml` (`status = "NOT_FOUND"`).
pub fn code_from_name(name: &str) -> Option<Code> {
    const ALL: [Code; 17] = [
        Code::Ok,
        Code::Cancelled,
        Code::Unknown,
        Code::InvalidArgument,
        Code::DeadlineExceeded,
        Code::NotFound,
        Code::AlreadyExists,
        Code::PermissionDenied,
        Code::ResourceExhausted,
        Code::FailedPrecondition,
        Code::Aborted,
        Code::OutOfRange,
        Code::Unimplemented,
        Code::Internal,
        Code::Unavailable,
        Code::DataLoss,
        Code::Unauthenticated,
    ];
    ALL.into_iter().find(|c| code_name(*c) == name)
}

pub type Result<T, E = EnvError> = std::result::Result<T, E>;
