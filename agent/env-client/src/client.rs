//! A client for one env server: connection with bounded retries, the version
//! handshake, and every unary call of the API under a deadline.
use std::collections::HashMap;
use std::future::Future;
use std::time::{Duration, Instant};

use tonic::Request;
use tonic::transport::{Channel, Endpoint};
use tonic_health::pb::health_client::HealthClient;
use tonic_health::pb::{HealthCheckRequest, health_check_response::ServingStatus};

use crate::error::{EnvError, Result};
use crate::proto;
use crate::proto::env_service_client::EnvServiceClient;
use crate::reply::{ResetResult, StepResult};
use crate::session::Session;
use crate::space::{AutoresetMode, EnvSpec};
use crate::tensor::Tensor;
use crate::value::{Kwargs, kwargs_to_proto};

/// The API version this client speaks (`proto/million/env/v1`).
pub const API_VERSION: (u32, u32) = (1, 0);

/// Deadlines of the calls.
#[derive(Clone, Debug)]
pub struct Timeouts {
    /// TCP connect of one attempt.
    pub connect: Duration,
    /// Handshake, ListEnvs, Close, GetStats, health.
    pub call: Duration,
    /// Make: building simulators can take long (a server's first Meta-World
    /// ML45 Make builds the benchmark, about a minute; the bundled server asks
    /// clients to allow ten).
    pub make: Duration,
    /// Reset and Step, unary or one reply on the Session stream.
    pub step: Duration,
}

impl Default for Timeouts {
    fn default() -> Self {
        Timeouts {
            connect: Duration::from_secs(5),
            call: Duration::from_secs(10),
            make: Duration::from_secs(600),
            step: Duration::from_secs(60),
        }
    }
}

/// Exponential backoff for (re)connecting, bounded in attempts and time.
#[derive(Clone, Debug)]
pub struct RetryPolicy {
    pub initial_backoff: Duration,
    pub max_backoff: Duration,
    /// Give up after this many attempts...
    pub max_attempts: u32,
    /// ...or once this much time has passed since the first attempt.
    pub max_elapsed: Duration,
}

impl Default for RetryPolicy {
    fn default() -> Self {
        RetryPolicy {
            initial_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(2),
            max_attempts: 30,
            max_elapsed: Duration::from_secs(30),
        }
    }
}

#[derive(Clone, Debug)]
pub struct ClientConfig {
    pub timeouts: Timeouts,
    pub retry: RetryPolicy,
    /// Sent in the handshake for the server's logs.
    pub client_name: String,
    /// Largest reply accepted (observations with images can be large).
    pub max_message_bytes: usize,
    /// The version announced in the handshake; only tests change it.
    pub api_version: (u32, u32),
}

impl Default for ClientConfig {
    fn default() -> Self {
        ClientConfig {
            timeouts: Timeouts::default(),
            retry: RetryPolicy::default(),
            client_name: concat!("million-env/", env!("CARGO_PKG_VERSION")).to_owned(),
            max_message_bytes: 256 << 20,
            api_version: API_VERSION,
        }
    }
}

/// What the server said about itself in the handshake.
#[derive(Clone, Debug, PartialEq)]
pub struct ServerInfo {
    pub version: (u32, u32),
    pub name: String,
    pub max_envs_per_handle: u32,
    pub max_envs_total: u32,
    pub autoreset_modes: Vec<AutoresetMode>,
    pub streaming: bool,
}

/// A connected, handshaken client of one server. Cloning shares the connection.
#[derive(Clone, Debug)]
pub struct EnvClient {
    addr: String,
    channel: Channel,
    inner: EnvServiceClient<Channel>,
    server: ServerInfo,
    config: ClientConfig,
}

/// `host:port` or a full URI, as tonic wants it.
fn endpoint_uri(addr: &str) -> String {
    if addr.contains("://") {
        addr.to_owned()
    } else {
        format!("http://{addr}")
    }
}

impl EnvClient {
    /// Connects and handshakes, retrying with exponential backoff while the
    /// server is unreachable; a version mismatch fails at once.
    pub async fn connect(addr: &str, config: ClientConfig) -> Result<Self> {
        let start = Instant::now();
        let retry = &config.retry;
        let mut backoff = retry.initial_backoff;
        let mut attempts = 0;
        loop {
            attempts += 1;
            let last_error = match Self::connect_once(addr, &config).await {
                Ok(client) => {
                    if attempts > 1 {
                        tracing::info!(addr, attempts, "connected to env server");
                    }
                    return Ok(client);
                }
                Err(e) if e.is_connection_loss() || matches!(e, EnvError::Unreachable { .. }) => {
                    e.to_string()
                }
                Err(e) => return Err(e),
            };
            let elapsed = start.elapsed();
            if attempts >= retry.max_attempts || elapsed + backoff > retry.max_elapsed {
                return Err(EnvError::Unreachable {
                    addr: addr.to_owned(),
                    attempts,
                    elapsed,
                    last_error,
                });
            }
            tracing::debug!(addr, attempts, ?backoff, %last_error, "env server not reachable yet");
            tokio::time::sleep(backoff).await;
            backoff = (backoff * 2).min(retry.max_backoff);
        }
    }

    async fn connect_once(addr: &str, config: &ClientConfig) -> Result<Self> {
        let unreachable = |e: String| EnvError::Unreachable {
            addr: addr.to_owned(),
            attempts: 1,
            elapsed: Duration::ZERO,
            last_error: e,
        };
        let endpoint = Endpoint::from_shared(endpoint_uri(addr))
            .map_err(|e| EnvError::InvalidInput(format!("bad server address {addr:?}: {e}")))?
            .connect_timeout(config.timeouts.connect)
            .tcp_nodelay(true);
        let channel = match tokio::time::timeout(config.timeouts.connect, endpoint.connect()).await
        {
            Ok(Ok(ch)) => ch,
            Ok(Err(e)) => return Err(unreachable(format!("{e}: {}", source_chain(&e)))),
            Err(_) => return Err(unreachable("connect timed out".into())),
        };
        let inner = EnvServiceClient::new(channel.clone())
            .max_decoding_message_size(config.max_message_bytes)
            .max_encoding_message_size(config.max_message_bytes);
        let mut client = EnvClient {
            addr: addr.to_owned(),
            channel,
            inner,
            server: ServerInfo {
                version: (0, 0),
                name: String::new(),
                max_envs_per_handle: 0,
                max_envs_total: 0,
                autoreset_modes: Vec::new(),
                streaming: false,
            },
            config: config.clone(),
        };
        let (major, minor) = config.api_version;
        let reply = client
            .handshake_raw(proto::HandshakeRequest {
                client_version: Some(proto::ApiVersion { major, minor }),
                client_name: config.client_name.clone(),
            })
            .await;
        let reply = match reply {
            Err(EnvError::Rpc { status, .. })
                if status.code() == tonic::Code::FailedPrecondition =>
            {
                return Err(EnvError::VersionMismatch {
                    addr: addr.to_owned(),
                    client: format!("{major}.{minor}"),
                    detail: format!("the server refused the handshake: {}", status.message()),
                });
            }
            other => other?,
        };
        let version = reply
            .server_version
            .map(|v| (v.major, v.minor))
            .ok_or_else(|| EnvError::protocol(addr, "handshake reply without a version"))?;
        if version.0 != major {
            return Err(EnvError::VersionMismatch {
                addr: addr.to_owned(),
                client: format!("{major}.{minor}"),
                detail: format!("the server speaks {}.{}", version.0, version.1),
            });
        }
        let caps = reply.capabilities.unwrap_or_default();
        client.server = ServerInfo {
            version,
            name: reply.server_name,
            max_envs_per_handle: caps.max_envs_per_handle,
            max_envs_total: caps.max_envs_total,
            autoreset_modes: caps
                .autoreset_modes
                .iter()
                .map(|&m| AutoresetMode::from_proto(m))
                .collect::<std::result::Result<_, _>>()
                .map_err(|e| EnvError::protocol(addr, e))?,
            streaming: caps.streaming,
        };
        Ok(client)
    }

    pub fn addr(&self) -> &str {
        &self.addr
    }

    pub fn server(&self) -> &ServerInfo {
        &self.server
    }

    pub fn config(&self) -> &ClientConfig {
        &self.config
    }

    /// The underlying connection, for other services on the same server.
    pub fn channel(&self) -> Channel {
        self.channel.clone()
    }

    /// Runs one call under `deadline`, both as the grpc-timeout the server sees
    /// and as a local timer, so a hung server cannot hang the client.
    async fn call<T, F>(&self, call: &'static str, deadline: Duration, fut: F) -> Result<T>
    where
        F: Future<Output = std::result::Result<tonic::Response<T>, tonic::Status>>,
    {
        match tokio::time::timeout(deadline, fut).await {
            Ok(Ok(resp)) => Ok(resp.into_inner()),
            Ok(Err(status)) if status.code() == tonic::Code::DeadlineExceeded => {
                Err(EnvError::Deadline {
                    addr: self.addr.clone(),
                    call,
                    deadline,
                })
            }
            Ok(Err(status)) => Err(EnvError::Rpc {
                addr: self.addr.clone(),
                call,
                status,
            }),
            Err(_) => Err(EnvError::Deadline {
                addr: self.addr.clone(),
                call,
                deadline,
            }),
        }
    }

    fn request<T>(msg: T, deadline: Duration) -> Request<T> {
        let mut req = Request::new(msg);
        req.set_timeout(deadline);
        req
    }

    pub async fn handshake_raw(
        &self,
        req: proto::HandshakeRequest,
    ) -> Result<proto::HandshakeResponse> {
        let d = self.config.timeouts.call;
        let mut c = self.inner.clone();
        self.call("Handshake", d, c.handshake(Self::request(req, d)))
            .await
    }

    /// grpc.health.v1 status of the whole server (empty service name).
    pub async fn health(&self) -> Result<ServingStatus> {
        let d = self.config.timeouts.call;
        let mut c = HealthClient::new(self.channel.clone());
        let reply = self
            .call(
                "Health.Check",
                d,
                c.check(Self::request(
                    HealthCheckRequest {
                        service: String::new(),
                    },
                    d,
                )),
            )
            .await?;
        ServingStatus::try_from(reply.status)
            .map_err(|_| EnvError::protocol(&self.addr, format!("health status {}", reply.status)))
    }

    pub async fn list_envs(&self) -> Result<Vec<proto::EnvIdInfo>> {
        let d = self.config.timeouts.call;
        let mut c = self.inner.clone();
        Ok(self
            .call(
                "ListEnvs",
                d,
                c.list_envs(Self::request(proto::ListEnvsRequest {}, d)),
            )
            .await?
            .envs)
    }

    pub async fn make_raw(&self, req: proto::MakeRequest) -> Result<proto::MakeResponse> {
        let d = self.config.timeouts.make;
        let mut c = self.inner.clone();
        self.call("Make", d, c.make(Self::request(req, d))).await
    }

    /// Makes `num_envs` envs; returns the handle and the parsed spec.
    pub async fn make(
        &self,
        env_id: &str,
        kwargs: &Kwargs,
        num_envs: usize,
        autoreset: AutoresetMode,
    ) -> Result<(String, EnvSpec)> {
        let num_envs = u32::try_from(num_envs)
            .map_err(|_| EnvError::InvalidInput(format!("num_envs {num_envs} too large")))?;
        let reply = self
            .make_raw(proto::MakeRequest {
                env_id: env_id.to_owned(),
                kwargs: kwargs_to_proto(kwargs),
                num_envs,
                autoreset_mode: autoreset.to_proto() as i32,
            })
            .await?;
        let spec = EnvSpec::from_proto(
            reply
                .spec
                .as_ref()
                .ok_or_else(|| EnvError::protocol(&self.addr, "make reply without a spec"))?,
        )
        .map_err(|e| EnvError::protocol(&self.addr, format!("spec of {env_id}: {e}")))?;
        if spec.num_envs != num_envs as usize {
            return Err(EnvError::protocol(
                &self.addr,
                format!("asked for {num_envs} envs, the spec says {}", spec.num_envs),
            ));
        }
        Ok((reply.handle, spec))
    }

    pub async fn reset_raw(&self, req: proto::ResetRequest) -> Result<proto::ResetResponse> {
        let d = self.config.timeouts.step;
        let mut c = self.inner.clone();
        self.call("Reset", d, c.reset(Self::request(req, d))).await
    }

    /// Resets the envs `indices` (all when empty) with `seeds` (none when empty).
    pub async fn reset(&self, handle: &str, indices: &[u32], seeds: &[i64]) -> Result<ResetResult> {
        let reply = self
            .reset_raw(reset_request(handle, indices, seeds))
            .await?;
        ResetResult::from_proto(&self.addr, reply)
    }

    pub async fn step_raw(&self, req: proto::StepRequest) -> Result<proto::StepResponse> {
        let d = self.config.timeouts.step;
        let mut c = self.inner.clone();
        self.call("Step", d, c.step(Self::request(req, d))).await
    }

    pub async fn step(&self, handle: &str, action: &Tensor) -> Result<StepResult> {
        let reply = self
            .step_raw(proto::StepRequest {
                handle: handle.to_owned(),
                action: Some(action.to_proto()),
            })
            .await?;
        StepResult::from_proto(&self.addr, reply)
    }

    pub async fn close(&self, handle: &str) -> Result<()> {
        let d = self.config.timeouts.call;
        let mut c = self.inner.clone();
        self.call(
            "Close",
            d,
            c.close(Self::request(
                proto::CloseRequest {
                    handle: handle.to_owned(),
                },
                d,
            )),
        )
        .await
        .map(|_| ())
    }

    pub async fn stats(&self) -> Result<HashMap<String, f64>> {
        let d = self.config.timeouts.call;
        let mut c = self.inner.clone();
        Ok(self
            .call(
                "GetStats",
                d,
                c.get_stats(Self::request(proto::GetStatsRequest {}, d)),
            )
            .await?
            .counters)
    }

    /// Opens a pipelined Session stream (see `Session`).
    pub fn session(&self) -> Session {
        Session::open(
            self.addr.clone(),
            self.inner.clone(),
            self.config.timeouts.step,
        )
    }
}

pub(crate) fn reset_request(handle: &str, indices: &[u32], seeds: &[i64]) -> proto::ResetRequest {
    proto::ResetRequest {
        handle: handle.to_owned(),
        env_indices: indices.to_vec(),
        seeds: seeds.to_vec(),
        options: HashMap::new(),
    }
}

fn source_chain(e: &dyn std::error::Error) -> String {
    let mut parts = Vec::new();
    let mut cur = e.source();
    while let Some(s) = cur {
        parts.push(s.to_string());
        cur = s.source();
    }
    parts.join(": ")
}
