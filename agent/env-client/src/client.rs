//! A client for one env server: connection with bounded retries, the version
//! handshake, and every unary call of the API under a deadline.
use std::collections::HashMap;
use std::future::Future;
use std::time::{Duration, Instant};

use tonic::Request;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, Endpoint};
use tonic_health::pb::health_client::HealthClient;
use tonic_health::pb::{HealthCheckRequest, health_check_response::ServingStatus};

use crate::access::{AuthInterceptor, TlsOptions, Token};
use crate::error::{EnvError, Result};
use crate::proto;
use crate::proto::env_service_client::EnvServiceClient;
use crate::reply::{ResetResult, StepResult};
use crate::session::Session;
use crate::space::{AutoresetMode, EnvSpec};
use crate::tensor::Tensor;
use crate::value::{Kwargs, kwargs_to_proto};

/// The API version this client speaks (`proto/million/env/v1`).
pub const API_VERSION: (u32, u32) = (1, 1);

/// The optional feature that serves the `Render` RPC (`Capabilities.features`).
pub const FEATURE_RENDER: &str = "render";

/// The API's maximum message size (env.proto), the server's limit too: a larger
/// request would only be refused by the server after being sent.
pub const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// A connection whose every call carries the token, when there is one.
pub type Transport = InterceptedService<Channel, AuthInterceptor>;

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
    /// Largest request sent and reply accepted (the API's maximum by default).
    pub max_message_bytes: usize,
    /// The version announced in the handshake; only tests change it.
    pub api_version: (u32, u32),
    /// The server's shared token, sent with every call (`--env-token`).
    pub token: Option<Token>,
    /// TLS towards the server (`--env-tls-ca`); plaintext when none.
    pub tls: Option<TlsOptions>,
}

impl Default for ClientConfig {
    fn default() -> Self {
        ClientConfig {
            timeouts: Timeouts::default(),
            retry: RetryPolicy::default(),
            client_name: concat!("million-env/", env!("CARGO_PKG_VERSION")).to_owned(),
            max_message_bytes: MAX_MESSAGE_BYTES,
            api_version: API_VERSION,
            token: None,
            tls: None,
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
    /// Optional features by name (API 1.1), e.g. [`FEATURE_RENDER`].
    pub features: Vec<String>,
}

impl ServerInfo {
    pub fn has_feature(&self, name: &str) -> bool {
        self.features.iter().any(|f| f == name)
    }
}

/// RGB frames from `Render`: `rows` frames of `height` x `width` pixels, row-major
/// `[rows, height, width, 3]` bytes, row 0 of each frame at its top.
#[derive(Clone, Debug, PartialEq)]
pub struct Frames {
    pub rows: usize,
    pub height: usize,
    pub width: usize,
    pub data: bytes::Bytes,
    /// The env index each frame belongs to.
    pub env_indices: Vec<u32>,
}

impl Frames {
    /// The RGB bytes of frame `row` (`height * width * 3`).
    pub fn frame(&self, row: usize) -> &[u8] {
        let n = self.height * self.width * 3;
        &self.data[row * n..(row + 1) * n]
    }
}

/// A connected, handshaken client of one server. Cloning shares the connection.
#[derive(Clone, Debug)]
pub struct EnvClient {
    addr: String,
    channel: Transport,
    inner: EnvServiceClient<Transport>,
    server: ServerInfo,
    config: ClientConfig,
}

/// `host:port` or a full URI, as tonic wants it (https when TLS is on).
fn endpoint_uri(addr: &str, tls: bool) -> String {
    if addr.contains("://") {
        addr.to_owned()
    } else if tls {
        format!("https://{addr}")
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
        let bad_address = |e: tonic::transport::Error| {
            EnvError::InvalidInput(format!("bad server address {addr:?}: {e}"))
        };
        let mut endpoint = Endpoint::from_shared(endpoint_uri(addr, config.tls.is_some()))
            .map_err(bad_address)?
            .connect_timeout(config.timeouts.connect)
            .tcp_nodelay(true);
        if let Some(tls) = &config.tls {
            endpoint = endpoint
                .tls_config(tls.client_config())
                .map_err(bad_address)?;
        }
        let channel = match tokio::time::timeout(config.timeouts.connect, endpoint.connect()).await
        {
            Ok(Ok(ch)) => ch,
            Ok(Err(e)) => return Err(unreachable(format!("{e}: {}", source_chain(&e)))),
            Err(_) => return Err(unreachable("connect timed out".into())),
        };
        let channel = InterceptedService::new(channel, AuthInterceptor::new(config.token.as_ref()));
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
                features: Vec::new(),
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
            features: caps.features,
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

    /// The underlying connection (with the token), for other services on the
    /// same server.
    pub fn channel(&self) -> Transport {
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
        let request = make_request(env_id, kwargs, num_envs, autoreset)?;
        let reply = self.make_raw(request).await?;
        self.parse_made(env_id, num_envs, reply)
    }

    /// True when the server takes `make` on a Session stream (API 1.1).
    pub fn makes_on_streams(&self) -> bool {
        self.server.version >= (1, 1) && self.server.streaming
    }

    /// The handle and checked spec of a Make reply (unary or on a stream).
    pub(crate) fn parse_made(
        &self,
        env_id: &str,
        num_envs: usize,
        reply: proto::MakeResponse,
    ) -> Result<(String, EnvSpec)> {
        let spec = EnvSpec::from_proto(
            reply
                .spec
                .as_ref()
                .ok_or_else(|| EnvError::protocol(&self.addr, "make reply without a spec"))?,
        )
        .map_err(|e| EnvError::protocol(&self.addr, format!("spec of {env_id}: {e}")))?;
        if spec.num_envs != num_envs {
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

    pub async fn render_raw(&self, req: proto::RenderRequest) -> Result<proto::RenderResponse> {
        let d = self.config.timeouts.step;
        let mut c = self.inner.clone();
        self.call("Render", d, c.render(Self::request(req, d)))
            .await
    }

    /// RGB frames of the envs `indices` (all when empty) of `handle`; `width`/`height`
    /// 0 and `camera` "" take the server's defaults. Needs the server's
    /// [`FEATURE_RENDER`]; an env that cannot draw itself is `UNIMPLEMENTED`.
    pub async fn render(
        &self,
        handle: &str,
        indices: &[u32],
        width: u32,
        height: u32,
        camera: &str,
    ) -> Result<Frames> {
        if !self.server.has_feature(FEATURE_RENDER) {
            return Err(EnvError::InvalidInput(format!(
                "the env server at {} does not render (no {FEATURE_RENDER:?} feature)",
                self.addr
            )));
        }
        let reply = self
            .render_raw(proto::RenderRequest {
                handle: handle.to_owned(),
                env_indices: indices.to_vec(),
                width,
                height,
                camera: camera.to_owned(),
            })
            .await?;
        let bad = |m: String| EnvError::protocol(&self.addr, format!("Render reply: {m}"));
        let frames = Tensor::from_proto(reply.frames.ok_or_else(|| bad("no frames".into()))?)
            .map_err(bad)?;
        let shape = frames.shape().to_vec();
        if frames.dtype() != crate::tensor::DType::UInt8 || shape.len() != 4 || shape[3] != 3 {
            return Err(bad(format!(
                "frames must be uint8 [rows, height, width, 3], got {:?} {shape:?}",
                frames.dtype()
            )));
        }
        if shape[0] != reply.env_indices.len()
            || (width > 0 && shape[2] != width as usize)
            || (height > 0 && shape[1] != height as usize)
        {
            return Err(bad(format!(
                "frames of shape {shape:?} for {} envs asked at {width} x {height}",
                reply.env_indices.len()
            )));
        }
        Ok(Frames {
            rows: shape[0],
            height: shape[1],
            width: shape[2],
            data: frames.data().clone(),
            env_indices: reply.env_indices,
        })
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

pub(crate) fn make_request(
    env_id: &str,
    kwargs: &Kwargs,
    num_envs: usize,
    autoreset: AutoresetMode,
) -> Result<proto::MakeRequest> {
    let num_envs = u32::try_from(num_envs)
        .map_err(|_| EnvError::InvalidInput(format!("num_envs {num_envs} too large")))?;
    Ok(proto::MakeRequest {
        env_id: env_id.to_owned(),
        kwargs: kwargs_to_proto(kwargs),
        num_envs,
        autoreset_mode: autoreset.to_proto() as i32,
    })
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
