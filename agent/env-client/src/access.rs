//! Reaching a guarded server: the shared token (sent as gRPC metadata
//! `authorization: Bearer <token>`, what the server's interceptor checks) and
//! TLS with the CA certificate that signed the server's certificate.
use std::fmt;
use std::path::{Path, PathBuf};

use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::Interceptor;
use tonic::transport::{Certificate, ClientTlsConfig};

/// The environment variable a token may come from (server and clients alike).
pub const TOKEN_ENV_VAR: &str = "MILLION_ENV_TOKEN";

/// Why the token or the TLS settings cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum AccessError {
    #[error("the env-server token is empty")]
    EmptyToken,
    #[error("the env-server token must be printable ASCII (it travels as a gRPC header)")]
    TokenNotAscii,
    #[error("cannot read the TLS CA certificate {path}: {source}")]
    ReadCa {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} holds no PEM certificate")]
    NotPem { path: PathBuf },
}

/// A shared secret. Its `Debug` never shows it, so configs can be logged.
#[derive(Clone, PartialEq, Eq)]
pub struct Token(String);

impl Token {
    pub fn new(token: impl Into<String>) -> Result<Self, AccessError> {
        let token = token.into();
        if token.trim().is_empty() {
            return Err(AccessError::EmptyToken);
        }
        if !token.bytes().all(|b| (0x20..0x7f).contains(&b)) {
            return Err(AccessError::TokenNotAscii);
        }
        Ok(Token(token))
    }

    /// `given`, else `$MILLION_ENV_TOKEN`, else none.
    pub fn from_arg_or_env(given: Option<String>) -> Result<Option<Self>, AccessError> {
        match given.or_else(|| std::env::var(TOKEN_ENV_VAR).ok().filter(|t| !t.is_empty())) {
            Some(t) => Token::new(t).map(Some),
            None => Ok(None),
        }
    }

    fn header(&self) -> MetadataValue<Ascii> {
        // Printable ASCII was checked in `new`, so this cannot fail.
        format!("Bearer {}", self.0)
            .parse()
            .expect("a printable ASCII token is a valid header value")
    }
}

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

/// TLS towards the server: the CA that signed its certificate (PEM).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TlsOptions {
    pub ca_pem: Vec<u8>,
    /// The name the server's certificate must carry; default: the address's host.
    pub domain: Option<String>,
}

impl TlsOptions {
    pub fn from_ca_file(path: &Path) -> Result<Self, AccessError> {
        let ca_pem = std::fs::read(path).map_err(|source| AccessError::ReadCa {
            path: path.to_owned(),
            source,
        })?;
        if !String::from_utf8_lossy(&ca_pem).contains("-----BEGIN CERTIFICATE-----") {
            return Err(AccessError::NotPem {
                path: path.to_owned(),
            });
        }
        Ok(TlsOptions {
            ca_pem,
            domain: None,
        })
    }

    pub(crate) fn client_config(&self) -> ClientTlsConfig {
        let config =
            ClientTlsConfig::new().ca_certificate(Certificate::from_pem(self.ca_pem.clone()));
        match &self.domain {
            Some(domain) => config.domain_name(domain.clone()),
            None => config,
        }
    }
}

/// Adds the bearer token to every call (a no-op without a token).
#[derive(Clone, Debug, Default)]
pub struct AuthInterceptor {
    header: Option<MetadataValue<Ascii>>,
}

impl AuthInterceptor {
    pub fn new(token: Option<&Token>) -> Self {
        AuthInterceptor {
            header: token.map(Token::header),
        }
    }
}

impl Interceptor for AuthInterceptor {
    fn call(
        &mut self,
        mut request: tonic::Request<()>,
    ) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(header) = &self.header {
            request
                .metadata_mut()
                .insert("authorization", header.clone());
        }
        Ok(request)
    }
}
