//! Runs `million-env-server` processes on this machine: what `million train`
//! does when no `--env-server` is given, and what the integration tests use.
//!
//! A server is started on port 0 and reports the port it got on its first
//! stdout line (`listening on HOST:PORT`), so concurrent starts never race for a
//! port. It is ready once grpc.health answers SERVING, and killed when dropped.

use std::path::{Path, PathBuf};
use std::process::{ExitStatus, Stdio};
use std::time::{Duration, Instant};

use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};
use tonic_health::pb::health_check_response::ServingStatus;

use crate::client::{ClientConfig, EnvClient, RetryPolicy};

/// Why a local server could not be started.
#[derive(Debug, thiserror::Error)]
pub enum LocalServerError {
    #[error(
        "million-env-server not found (looked for {0}); run `make setup`, or set \
         MILLION_ENV_SERVER to the server's path"
    )]
    BinaryMissing(PathBuf),
    #[error("cannot start {binary}: {source}")]
    Spawn {
        binary: PathBuf,
        source: std::io::Error,
    },
    #[error("million-env-server exited before it listened ({0}); its stderr says why")]
    ExitedEarly(String),
    #[error("million-env-server on {addr} was not healthy within {waited:?}")]
    NotReady { addr: String, waited: Duration },
}

/// Extra arguments for the server process.
#[derive(Clone, Debug)]
pub struct LocalServerOptions {
    pub log_level: String,
    /// Meta-World benchmarks to build before serving (`--preload`).
    pub preload: Vec<String>,
    /// How long to wait for health (a preload of ML45 takes about a minute).
    pub ready_timeout: Duration,
    /// More command-line arguments (`--tls-cert`, `--max-envs-total`, ...).
    pub extra_args: Vec<String>,
    /// Environment variables of the process (`MILLION_ENV_TOKEN`).
    pub env: Vec<(String, String)>,
    /// How the readiness check connects (token, TLS) to a guarded server.
    pub client: ClientConfig,
}

impl Default for LocalServerOptions {
    fn default() -> Self {
        LocalServerOptions {
            log_level: "WARNING".into(),
            preload: Vec::new(),
            ready_timeout: Duration::from_secs(180),
            extra_args: Vec::new(),
            env: Vec::new(),
            client: ClientConfig::default(),
        }
    }
}

/// A running `million-env-server` child process, killed on drop.
#[derive(Debug)]
pub struct LocalServer {
    binary: PathBuf,
    options: LocalServerOptions,
    port: u16,
    addr: String,
    child: Option<Child>,
}

/// The server binary: `$MILLION_ENV_SERVER`, else `.venv/bin/million-env-server`
/// under `$MILLION_ROOT`, under an ancestor of the running executable (the
/// repository, for `target/release/million`), or under this crate's repository.
pub fn default_server_binary() -> Result<PathBuf, LocalServerError> {
    if let Some(path) = std::env::var_os("MILLION_ENV_SERVER") {
        let path = PathBuf::from(path);
        return if path.exists() {
            Ok(path)
        } else {
            Err(LocalServerError::BinaryMissing(path))
        };
    }
    let relative = Path::new(".venv/bin/million-env-server");
    find_in_repository(relative)
        .ok_or_else(|| LocalServerError::BinaryMissing(relative.to_path_buf()))
}

/// `relative` (e.g. `.venv/bin/python`) under the first repository root that has it:
/// `$MILLION_ROOT`, an ancestor of the running executable (the repository, for
/// `target/release/million`), or this crate's repository.
pub fn find_in_repository(relative: &Path) -> Option<PathBuf> {
    let mut roots: Vec<PathBuf> = Vec::new();
    if let Some(root) = std::env::var_os("MILLION_ROOT") {
        roots.push(root.into());
    }
    if let Ok(exe) = std::env::current_exe() {
        roots.extend(exe.ancestors().skip(1).map(Path::to_path_buf));
    }
    roots.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("../.."));
    roots
        .iter()
        .map(|root| root.join(relative))
        .find(|candidate| candidate.exists())
}

impl LocalServer {
    /// Starts a server on a free loopback port and waits until it is healthy.
    pub async fn start(
        binary: &Path,
        options: LocalServerOptions,
    ) -> Result<Self, LocalServerError> {
        let mut server = LocalServer {
            binary: binary.to_path_buf(),
            options,
            port: 0,
            addr: String::new(),
            child: None,
        };
        server.launch(0).await?;
        server.wait_ready().await?;
        Ok(server)
    }

    /// Starts `count` servers concurrently (each builds its own benchmarks).
    pub async fn start_many(
        binary: &Path,
        options: LocalServerOptions,
        count: usize,
    ) -> Result<Vec<Self>, LocalServerError> {
        let starts = (0..count).map(|_| LocalServer::start(binary, options.clone()));
        futures::future::try_join_all(starts).await
    }

    /// `127.0.0.1:PORT`, as the pool and the client take it.
    pub fn addr(&self) -> &str {
        &self.addr
    }

    pub fn port(&self) -> u16 {
        self.port
    }

    /// The process id while the server runs.
    pub fn pid(&self) -> Option<u32> {
        self.child.as_ref().and_then(Child::id)
    }

    /// Waits until the process exits by itself (or was killed from outside);
    /// `None` when no process is running.
    pub async fn wait_exit(&mut self) -> Option<std::io::Result<ExitStatus>> {
        let status = self.child.as_mut()?.wait().await;
        self.child = None;
        Some(status)
    }

    /// Starts the server again on its port and waits until it is healthy.
    pub async fn relaunch(&mut self) -> Result<(), LocalServerError> {
        self.kill().await;
        self.launch(self.port).await?;
        self.wait_ready().await
    }

    /// Kills the process (SIGKILL: its clients get no goodbye, as in a crash).
    pub async fn kill(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill().await;
        }
    }

    /// Kills the server and starts a new one on the same port, without waiting
    /// for it to be healthy (tests of reconnection use this).
    pub async fn restart(&mut self) -> Result<(), LocalServerError> {
        self.kill().await;
        self.launch(self.port).await
    }

    /// Waits until grpc.health answers SERVING.
    pub async fn wait_ready(&self) -> Result<(), LocalServerError> {
        let waited = self.options.ready_timeout;
        let not_ready = || LocalServerError::NotReady {
            addr: self.addr.clone(),
            waited,
        };
        let start = Instant::now();
        let config = ClientConfig {
            retry: RetryPolicy {
                max_attempts: u32::MAX,
                max_elapsed: waited,
                ..RetryPolicy::default()
            },
            ..self.options.client.clone()
        };
        let client = EnvClient::connect(&self.addr, config)
            .await
            .map_err(|_| not_ready())?;
        while start.elapsed() < waited {
            if let Ok(ServingStatus::Serving) = client.health().await {
                return Ok(());
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        Err(not_ready())
    }

    async fn launch(&mut self, port: u16) -> Result<(), LocalServerError> {
        let mut command = Command::new(&self.binary);
        command
            .args(["--address", &format!("127.0.0.1:{port}")])
            .args(["--log-level", &self.options.log_level])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .kill_on_drop(true);
        for benchmark in &self.options.preload {
            command.args(["--preload", benchmark]);
        }
        command
            .args(&self.options.extra_args)
            .envs(self.options.env.iter().map(|(k, v)| (k, v)));
        // Its own process group: a Ctrl-C in the agent's terminal (SIGINT to the foreground
        // group) goes to the agent alone, which then evaluates, checkpoints and ends its
        // servers itself; in the agent's group the servers died first and the run's final
        // evaluation lost them (seen on a GPU machine: `timeout -s INT` signals the group).
        command.process_group(0);
        die_with_parent(&mut command);
        let mut child = command.spawn().map_err(|source| LocalServerError::Spawn {
            binary: self.binary.clone(),
            source,
        })?;
        let stdout = child.stdout.take().expect("stdout is piped");
        let mut lines = BufReader::new(stdout).lines();
        let addr = loop {
            match lines.next_line().await {
                Ok(Some(line)) => {
                    if let Some(addr) = line.strip_prefix("listening on ") {
                        break addr.trim().to_owned();
                    }
                }
                Ok(None) | Err(_) => {
                    let status = child
                        .wait()
                        .await
                        .map_or_else(|e| e.to_string(), |s| s.to_string());
                    return Err(LocalServerError::ExitedEarly(status));
                }
            }
        };
        // Keep draining stdout so the server never blocks on a full pipe.
        tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
        self.port = addr
            .rsplit(':')
            .next()
            .and_then(|p| p.parse().ok())
            .ok_or_else(|| {
                LocalServerError::ExitedEarly(format!("unparseable address {addr:?}"))
            })?;
        self.addr = format!("127.0.0.1:{}", self.port);
        self.child = Some(child);
        Ok(())
    }
}

/// A server started here must not outlive the process that started it: `kill_on_drop` only
/// runs when the owner is dropped, not when the agent is killed (SIGKILL, the OOM killer) —
/// seen: two servers left running for half an hour after a `million train` was killed.
/// On Linux the kernel sends the server SIGKILL when the thread that spawned it exits (here
/// a tokio worker, which lives as long as the runtime).
fn die_with_parent(command: &mut Command) {
    #[cfg(target_os = "linux")]
    // SAFETY: the closure runs in the forked child before exec and only calls prctl, which
    // is async-signal-safe.
    unsafe {
        command.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) == 0 {
                Ok(())
            } else {
                Err(std::io::Error::last_os_error())
            }
        });
    }
    #[cfg(not(target_os = "linux"))]
    let _ = command;
}
