//! The pipelined `Session` stream of one server: requests go out as soon as
//! they are sent, replies are read later, one per request, in order.
use std::collections::VecDeque;
use std::time::Duration;

use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio_stream::wrappers::UnboundedReceiverStream;

use crate::client::Transport;
use crate::error::{EnvError, Result};
use crate::proto::env_service_client::EnvServiceClient;
use crate::proto::{SessionRequest, SessionResponse, session_request, session_response};
use crate::reply::{ResetResult, StepResult};

/// A typed reply on the stream.
#[derive(Clone, Debug)]
pub enum SessionReply {
    Reset(ResetResult),
    Step(StepResult),
    /// A handle made on the stream (API 1.1), owned by it: the server closes it
    /// when the stream ends.
    /// Boxed: a spec is large, and steps (the common reply) should stay small.
    Make(Box<crate::proto::MakeResponse>),
    Closed,
}

/// One open Session stream. Dropping it ends the stream.
#[derive(Debug)]
pub struct Session {
    addr: String,
    requests: mpsc::UnboundedSender<SessionRequest>,
    replies: mpsc::UnboundedReceiver<std::result::Result<SessionResponse, tonic::Status>>,
    pending: VecDeque<u64>,
    next_id: u64,
    deadline: Duration,
    pump: JoinHandle<()>,
}

impl Drop for Session {
    fn drop(&mut self) {
        self.pump.abort();
    }
}

impl Session {
    /// Starts the stream. The call runs in its own task, so requests can be
    /// queued before the server's response headers arrive (a server may hold
    /// them back until its first reply).
    pub(crate) fn open(
        addr: String,
        mut client: EnvServiceClient<Transport>,
        deadline: Duration,
    ) -> Self {
        let (req_tx, req_rx) = mpsc::unbounded_channel();
        let (reply_tx, reply_rx) = mpsc::unbounded_channel();
        let pump = tokio::spawn(async move {
            let mut stream = match client.session(UnboundedReceiverStream::new(req_rx)).await {
                Ok(resp) => resp.into_inner(),
                Err(status) => {
                    let _ = reply_tx.send(Err(status));
                    return;
                }
            };
            loop {
                match stream.message().await {
                    Ok(Some(msg)) => {
                        if reply_tx.send(Ok(msg)).is_err() {
                            return;
                        }
                    }
                    Ok(None) => return,
                    Err(status) => {
                        let _ = reply_tx.send(Err(status));
                        return;
                    }
                }
            }
        });
        Session {
            addr,
            requests: req_tx,
            replies: reply_rx,
            pending: VecDeque::new(),
            next_id: 1,
            deadline,
            pump,
        }
    }

    pub fn addr(&self) -> &str {
        &self.addr
    }

    /// Requests sent whose replies were not read yet.
    pub fn in_flight(&self) -> usize {
        self.pending.len()
    }

    /// Queues a request under the next request id and returns that id.
    pub fn send(&mut self, request: session_request::Request) -> Result<u64> {
        let id = self.next_id;
        self.send_with_id(id, request)?;
        Ok(id)
    }

    /// Queues a request under a caller-chosen id (ids of later `send`s follow it).
    pub fn send_with_id(&mut self, id: u64, request: session_request::Request) -> Result<()> {
        self.requests
            .send(SessionRequest {
                request_id: id,
                request: Some(request),
            })
            .map_err(|_| EnvError::StreamClosed {
                addr: self.addr.clone(),
                detail: "the stream ended before the request could be sent".into(),
            })?;
        self.pending.push_back(id);
        self.next_id = id + 1;
        Ok(())
    }

    /// The next reply exactly as the server sent it (within the deadline).
    pub async fn recv_raw(&mut self) -> Result<SessionResponse> {
        self.recv_raw_within(self.deadline).await
    }

    async fn recv_raw_within(&mut self, deadline: Duration) -> Result<SessionResponse> {
        let expected = self.pending.pop_front();
        let reply = match tokio::time::timeout(deadline, self.replies.recv()).await {
            Err(_) => {
                return Err(EnvError::Deadline {
                    addr: self.addr.clone(),
                    call: "Session",
                    deadline,
                });
            }
            Ok(None) => {
                return Err(EnvError::StreamClosed {
                    addr: self.addr.clone(),
                    detail: format!(
                        "the server ended the stream with {} replies outstanding",
                        self.pending.len() + usize::from(expected.is_some())
                    ),
                });
            }
            Ok(Some(Err(status))) => {
                return Err(EnvError::Rpc {
                    addr: self.addr.clone(),
                    call: "Session",
                    status,
                });
            }
            Ok(Some(Ok(reply))) => reply,
        };
        if expected.is_none() {
            return Err(EnvError::protocol(
                &self.addr,
                "a Session reply nobody asked for",
            ));
        }
        Ok(reply)
    }

    /// The next reply, checked to answer the oldest outstanding request; an
    /// in-stream error becomes `EnvError::Rpc` with the server's status code.
    pub async fn recv(&mut self) -> Result<SessionReply> {
        self.recv_within(self.deadline).await
    }

    /// `recv` with another deadline (a `make` may take minutes).
    pub async fn recv_within(&mut self, deadline: Duration) -> Result<SessionReply> {
        let expected = self.pending.front().copied();
        let reply = self.recv_raw_within(deadline).await?;
        if Some(reply.request_id) != expected {
            return Err(EnvError::protocol(
                &self.addr,
                format!(
                    "Session reply for request {} where {expected:?} was due",
                    reply.request_id
                ),
            ));
        }
        match reply.response {
            Some(session_response::Response::Reset(r)) => {
                Ok(SessionReply::Reset(ResetResult::from_proto(&self.addr, r)?))
            }
            Some(session_response::Response::Step(s)) => {
                Ok(SessionReply::Step(StepResult::from_proto(&self.addr, s)?))
            }
            Some(session_response::Response::Make(m)) => Ok(SessionReply::Make(Box::new(m))),
            Some(session_response::Response::Close(_)) => Ok(SessionReply::Closed),
            Some(session_response::Response::Error(e)) => Err(EnvError::Rpc {
                addr: self.addr.clone(),
                call: "Session",
                status: tonic::Status::new(tonic::Code::from(e.code), e.message),
            }),
            None => Err(EnvError::protocol(
                &self.addr,
                "Session reply without a response",
            )),
        }
    }
}
