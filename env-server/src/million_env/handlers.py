"""EnvService's gRPC method handlers, built so that no request ever gets UNKNOWN.

The generated ``add_EnvServiceServicer_to_server`` decodes requests with
``FromString``; a request that is not a valid message then raises DecodeError
inside grpc, which answers UNKNOWN ("Unexpected <class DecodeError>..."). Here
each deserializer returns an ``UndecodableRequest`` instead of raising, and the
handler wrapper answers it with INVALID_ARGUMENT and a message saying what could
not be parsed. A Session stream answers an undecodable message with an ``error``
reply (request_id 0) and goes on, like any other invalid request in a stream.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import grpc
from google.protobuf.message import DecodeError, Message

from million_env._proto import env_pb2

SERVICE_DESCRIPTOR = env_pb2.DESCRIPTOR.services_by_name["EnvService"]
SERVICE_NAME = SERVICE_DESCRIPTOR.full_name


@dataclass(frozen=True)
class UndecodableRequest:
    """Stands in for a request message whose bytes did not parse."""

    message_type: str
    size: int
    reason: str

    def describe(self) -> str:
        return f"request is not a valid {self.message_type} ({self.size} bytes): {self.reason}"


def safe_deserializer(message_class: type[Message]) -> Callable[[bytes], Any]:
    """``message_class.FromString`` that returns an UndecodableRequest on bad bytes."""
    name = message_class.DESCRIPTOR.full_name

    def deserialize(data: bytes) -> Message | UndecodableRequest:
        try:
            return message_class.FromString(data)
        except (DecodeError, RuntimeError, ValueError) as err:
            # upb raises DecodeError; RuntimeError/ValueError cover recursion
            # limits and invalid UTF-8 in older runtimes.
            return UndecodableRequest(name, len(data), str(err) or type(err).__name__)

    return deserialize


OnUndecodable = Callable[[grpc.StatusCode], None]


def _guard_unary(
    method: Callable[[Any, grpc.aio.ServicerContext], Awaitable[Any]],
    on_undecodable: OnUndecodable,
) -> Callable[[Any, grpc.aio.ServicerContext], Awaitable[Any]]:
    async def handler(request: Any, context: grpc.aio.ServicerContext) -> Any:
        if isinstance(request, UndecodableRequest):
            on_undecodable(grpc.StatusCode.INVALID_ARGUMENT)
            await context.abort(grpc.StatusCode.INVALID_ARGUMENT, request.describe())
        return await method(request, context)

    return handler


def method_handlers(servicer: Any, on_undecodable: OnUndecodable) -> grpc.GenericRpcHandler:
    """A generic handler serving every EnvService method of ``servicer``.

    Unary methods are guarded here; streaming methods receive UndecodableRequest
    items in their request iterator and must answer them themselves."""
    handlers: dict[str, grpc.RpcMethodHandler] = {}
    for method in SERVICE_DESCRIPTOR.methods:
        request_class = getattr(env_pb2, method.input_type.name)
        response_class = getattr(env_pb2, method.output_type.name)
        implementation = getattr(servicer, method.name)
        deserializer = safe_deserializer(request_class)
        serializer = response_class.SerializeToString
        if method.client_streaming and method.server_streaming:
            handlers[method.name] = grpc.stream_stream_rpc_method_handler(
                implementation, request_deserializer=deserializer, response_serializer=serializer
            )
        elif not method.client_streaming and not method.server_streaming:
            handlers[method.name] = grpc.unary_unary_rpc_method_handler(
                _guard_unary(implementation, on_undecodable),
                request_deserializer=deserializer,
                response_serializer=serializer,
            )
        else:  # the API has no half-streaming methods; a new one must be wired here
            raise TypeError(f"{method.name}: half-streaming methods are not handled")
    return grpc.method_handlers_generic_handler(SERVICE_NAME, handlers)
