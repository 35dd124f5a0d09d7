//! Finding every env-server replica behind one name.
//!
//! A pool target (`--env-server`) is `host:port` or a URI. A name that resolves to
//! several addresses (Docker's service name when a service runs scaled, a Kubernetes
//! headless Service) stands for all of them: the pool opens envs on every address, and
//! re-resolves when a server is lost, so that a replica replaced under a new address
//! is found. A gRPC channel to the name would use only one of them.
use std::fmt::Debug;
use std::future::Future;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::time::Instant;

use crate::client::RetryPolicy;
use crate::error::{EnvError, Result};

pub type ResolveFuture<'a> =
    Pin<Box<dyn Future<Output = std::io::Result<Vec<String>>> + Send + 'a>>;

/// Turns a pool target into the addresses of its replicas (each usable as a target
/// of one server: `ip:port`, or `scheme://ip:port` for a URI).
pub trait Resolve: Debug + Send + Sync {
    fn resolve<'a>(&'a self, target: &'a str) -> ResolveFuture<'a>;
}

/// The system resolver (`getaddrinfo`: /etc/hosts, then DNS).
///
/// An IP literal is kept as written. When a name has both IPv4 and IPv6 addresses only
/// the IPv4 ones are used, so that a dual-stack host (`localhost`) counts once. `https`
/// targets are kept as written: TLS checks the server's name, which an address is not.
#[derive(Clone, Copy, Debug, Default)]
pub struct DnsResolver;

impl Resolve for DnsResolver {
    fn resolve<'a>(&'a self, target: &'a str) -> ResolveFuture<'a> {
        Box::pin(dns_resolve(target))
    }
}

/// `scheme://` (or ""), `host:port`, and the rest of a target.
fn split_target(target: &str) -> (&str, &str, &str) {
    let (scheme, rest) = match target.find("://") {
        Some(i) => target.split_at(i + 3),
        None => ("", target),
    };
    let (authority, tail) = match rest.find('/') {
        Some(i) => rest.split_at(i),
        None => (rest, ""),
    };
    (scheme, authority, tail)
}

async fn dns_resolve(target: &str) -> std::io::Result<Vec<String>> {
    let (scheme, authority, tail) = split_target(target);
    if scheme.eq_ignore_ascii_case("https://") || authority.parse::<SocketAddr>().is_ok() {
        return Ok(vec![target.to_owned()]);
    }
    let found: Vec<SocketAddr> = tokio::net::lookup_host(authority).await?.collect();
    let v4 = found.iter().any(|a| matches!(a.ip(), IpAddr::V4(_)));
    let mut addrs: Vec<String> = found
        .into_iter()
        .filter(|a| !v4 || a.is_ipv4())
        .map(|a| format!("{scheme}{a}{tail}"))
        .collect();
    // Sorted, so that every resolution of the same set lays envs out the same way.
    addrs.sort();
    addrs.dedup();
    Ok(addrs)
}

/// Resolves `target`, retrying with the policy's backoff while the name does not
/// resolve or has no address yet (replicas still starting).
pub(crate) async fn resolve_with_retry(
    resolver: &dyn Resolve,
    target: &str,
    retry: &RetryPolicy,
) -> Result<Vec<String>> {
    let start = Instant::now();
    let mut backoff = retry.initial_backoff;
    let mut attempts = 0;
    loop {
        attempts += 1;
        let last_error = match resolver.resolve(target).await {
            Ok(addrs) if !addrs.is_empty() => return Ok(addrs),
            Ok(_) => "no addresses".to_owned(),
            Err(e) => e.to_string(),
        };
        let elapsed = start.elapsed();
        if attempts >= retry.max_attempts || elapsed + backoff > retry.max_elapsed {
            return Err(EnvError::Unreachable {
                addr: target.to_owned(),
                attempts,
                elapsed,
                last_error: format!("resolving: {last_error}"),
            });
        }
        tracing::debug!(target, attempts, %last_error, "env server name not resolved yet");
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(retry.max_backoff);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_split_into_scheme_authority_and_path() {
        assert_eq!(split_target("env:50051"), ("", "env:50051", ""));
        assert_eq!(
            split_target("http://env:50051/x"),
            ("http://", "env:50051", "/x")
        );
    }

    #[tokio::test]
    async fn literals_stay_and_names_resolve_to_ipv4_first() {
        let r = DnsResolver;
        assert_eq!(r.resolve("127.0.0.1:7").await.unwrap(), vec!["127.0.0.1:7"]);
        assert_eq!(r.resolve("[::1]:7").await.unwrap(), vec!["[::1]:7"]);
        assert_eq!(
            r.resolve("https://envs.example:443").await.unwrap(),
            vec!["https://envs.example:443"]
        );
        assert_eq!(r.resolve("localhost:7").await.unwrap(), vec!["127.0.0.1:7"]);
        assert_eq!(
            r.resolve("http://localhost:7").await.unwrap(),
            vec!["http://127.0.0.1:7"]
        );
    }

    #[tokio::test]
    async fn an_unknown_name_is_unreachable_after_the_retries() {
        let retry = RetryPolicy {
            initial_backoff: std::time::Duration::from_millis(1),
            max_backoff: std::time::Duration::from_millis(1),
            max_attempts: 2,
            max_elapsed: std::time::Duration::from_secs(5),
        };
        let e = resolve_with_retry(&DnsResolver, "no-such-host.invalid:1", &retry)
            .await
            .unwrap_err();
        assert!(
            matches!(e, EnvError::Unreachable { attempts: 2, .. }),
            "{e}"
        );
    }
}
