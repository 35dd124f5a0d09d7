//! `--env-token` and `--env-tls-ca`: how `train`, `eval` and `env-check` reach
//! env servers that require a token or TLS.
use std::path::PathBuf;

use clap::Args;
use million_env::{TlsOptions, Token};

use crate::train::servers::EnvAccess;

#[derive(Debug, Clone, Default, Args)]
pub struct EnvAccessArgs {
    /// Shared token of the env servers, sent as `authorization: Bearer <token>`
    /// (default: $MILLION_ENV_TOKEN; prefer the variable, a command line is visible to others).
    #[arg(long = "env-token", value_name = "TOKEN")]
    pub env_token: Option<String>,
    /// CA certificate (PEM) that signed the env servers' TLS certificates; connects with TLS.
    #[arg(long = "env-tls-ca", value_name = "PEM")]
    pub env_tls_ca: Option<PathBuf>,
}

impl EnvAccessArgs {
    pub fn resolve(&self) -> anyhow::Result<EnvAccess> {
        let token = Token::from_arg_or_env(self.env_token.clone())?;
        let tls = self
            .env_tls_ca
            .as_deref()
            .map(TlsOptions::from_ca_file)
            .transpose()?;
        Ok(EnvAccess { token, tls })
    }
}
