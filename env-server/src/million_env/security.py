"""Who may call the server: an optional shared token and optional TLS.

The token travels as gRPC metadata ``authorization: Bearer <token>`` (what gRPC's
access-token call credentials send), so a client in any language can send it. A
call without it, or with another token, ends UNAUTHENTICATED before any handler
runs. ``grpc.health.v1`` stays open so that probes (grpc_health_probe,
Kubernetes) need no secret. The token itself is never logged or echoed.
"""

from __future__ import annotations

import hmac
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import grpc

TOKEN_ENV_VAR = "MILLION_ENV_TOKEN"
AUTH_HEADER = "authorization"
_BEARER = "bearer "
OPEN_SERVICES = ("grpc.health.v1.Health",)


class TlsConfigError(ValueError):
    """The TLS certificate or key cannot be used."""


@dataclass(frozen=True)
class ServerTls:
    """PEM certificate chain and private key the server presents."""

    cert_pem: bytes
    key_pem: bytes

    @staticmethod
    def from_files(cert: Path, key: Path) -> ServerTls:
        try:
            return ServerTls(cert.read_bytes(), key.read_bytes())
        except OSError as err:
            raise TlsConfigError(f"cannot read TLS file: {err}") from err

    def credentials(self) -> grpc.ServerCredentials:
        return grpc.ssl_server_credentials([(self.key_pem, self.cert_pem)])


def bearer_metadata(token: str | None) -> tuple[tuple[str, str], ...]:
    """The call metadata carrying ``token`` (none when there is no token)."""
    return () if not token else ((AUTH_HEADER, f"Bearer {token}"),)


def _service_of(method: str) -> str:
    # "/package.Service/Method" -> "package.Service"
    return method.lstrip("/").split("/", 1)[0]


def _presented_token(metadata: Any) -> str | None:
    for key, value in metadata or ():
        if key == AUTH_HEADER and isinstance(value, str) and value.lower().startswith(_BEARER):
            return value[len(_BEARER) :].strip()
    return None


def _refusal(handler: grpc.RpcMethodHandler, message: str) -> grpc.RpcMethodHandler:
    """A handler of the same kind as ``handler`` that only says UNAUTHENTICATED."""

    async def abort(_request: Any, context: grpc.aio.ServicerContext) -> None:
        await context.abort(grpc.StatusCode.UNAUTHENTICATED, message)

    kwargs = {
        "request_deserializer": None,  # the body is never parsed for a refused call
        "response_serializer": handler.response_serializer,
    }
    if handler.request_streaming and handler.response_streaming:
        return grpc.stream_stream_rpc_method_handler(abort, **kwargs)
    if handler.request_streaming:
        return grpc.stream_unary_rpc_method_handler(abort, **kwargs)
    if handler.response_streaming:
        return grpc.unary_stream_rpc_method_handler(abort, **kwargs)
    return grpc.unary_unary_rpc_method_handler(abort, **kwargs)


class TokenInterceptor(grpc.aio.ServerInterceptor):
    """Refuses every call whose bearer token is not ``token`` (health excepted)."""

    def __init__(self, token: str, on_refused: Callable[[grpc.StatusCode], None]) -> None:
        if not token:
            raise ValueError("an empty token would let everyone in")
        self._token = token.encode()
        self._on_refused = on_refused

    async def intercept_service(
        self,
        continuation: Callable[[grpc.HandlerCallDetails], Awaitable[grpc.RpcMethodHandler]],
        handler_call_details: grpc.HandlerCallDetails,
    ) -> grpc.RpcMethodHandler:
        handler = await continuation(handler_call_details)
        if handler is None or _service_of(handler_call_details.method) in OPEN_SERVICES:
            return handler
        presented = _presented_token(handler_call_details.invocation_metadata)
        if presented is not None and hmac.compare_digest(presented.encode(), self._token):
            return handler
        self._on_refused(grpc.StatusCode.UNAUTHENTICATED)
        reason = "missing" if presented is None else "wrong"
        return _refusal(
            handler,
            f"{reason} token: send metadata 'authorization: Bearer <token>' "
            f"with the server's token",
        )
