"""Numpy arrays and plain Python values to and from their proto messages.

Arrays travel as raw little-endian C-order bytes (``ndarray.tobytes``), never one
proto field per element.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from million_env._proto import env_pb2
from million_env.errors import invalid

_NUMPY_BY_DTYPE: dict[int, np.dtype] = {
    env_pb2.DTYPE_FLOAT32: np.dtype("<f4"),
    env_pb2.DTYPE_FLOAT64: np.dtype("<f8"),
    env_pb2.DTYPE_INT8: np.dtype("i1"),
    env_pb2.DTYPE_INT16: np.dtype("<i2"),
    env_pb2.DTYPE_INT32: np.dtype("<i4"),
    env_pb2.DTYPE_INT64: np.dtype("<i8"),
    env_pb2.DTYPE_UINT8: np.dtype("u1"),
    env_pb2.DTYPE_BOOL: np.dtype("?"),
}
_DTYPE_BY_KIND: dict[str, int] = {
    np.dtype(dt).str.lstrip("<>|="): code for code, dt in _NUMPY_BY_DTYPE.items()
}


_CODE_BY_NUMPY: dict[np.dtype, int] = {dt: code for code, dt in _NUMPY_BY_DTYPE.items()}


def dtype_to_proto(dtype: np.dtype | type) -> int:
    """The proto DType of a numpy dtype; strings (``str``/``object``) are DTYPE_STRING."""
    code = _CODE_BY_NUMPY.get(dtype)  # type: ignore[call-overload]
    if code is not None:
        return code
    dt = np.dtype(dtype)
    if dt.kind in ("U", "O", "S"):
        return env_pb2.DTYPE_STRING
    code = _DTYPE_BY_KIND.get(dt.str.lstrip("<>|="))
    if code is None:
        raise ValueError(f"numpy dtype {dt} has no counterpart in the env API")
    return code


def _dtype_name(code: int) -> str:
    return env_pb2.DType.Name(code) if code in env_pb2.DType.values() else f"dtype number {code}"


def dtype_to_numpy(code: int) -> np.dtype:
    """The little-endian numpy dtype of a proto DType (not DTYPE_STRING)."""
    dt = _NUMPY_BY_DTYPE.get(code)
    if dt is None:
        raise invalid(f"unsupported tensor dtype {_dtype_name(code)}")
    return dt


def encode_tensor(array: np.ndarray) -> env_pb2.Tensor:
    """One tensor message from an array (copied only if not little-endian C order)."""
    array = np.asarray(array)
    code = dtype_to_proto(array.dtype)
    if code == env_pb2.DTYPE_STRING:
        return env_pb2.Tensor(
            dtype=code, shape=array.shape, strings=[str(s) for s in array.reshape(-1)]
        )
    wire = _NUMPY_BY_DTYPE[code]
    if array.dtype != wire:  # big-endian input
        array = array.astype(wire)
    # tobytes writes C order whatever the memory layout, so no contiguous copy first.
    return env_pb2.Tensor(dtype=code, shape=array.shape, data=array.tobytes())


def decode_tensor(tensor: env_pb2.Tensor) -> np.ndarray:
    """The array a tensor message holds; INVALID_ARGUMENT if data and shape disagree."""
    shape = tuple(int(d) for d in tensor.shape)
    if any(d < 0 for d in shape):
        raise invalid(f"tensor shape {list(shape)} has a negative dimension")
    # Python integers: np.prod in int64 would wrap around for huge shapes and let
    # a tensor of 2**32 x 2**32 elements pass as 0 elements.
    count = math.prod(shape)
    if tensor.dtype == env_pb2.DTYPE_STRING:
        if len(tensor.strings) != count:
            raise invalid(
                f"string tensor of shape {list(shape)} needs {count} strings, "
                f"got {len(tensor.strings)}"
            )
        return np.array(list(tensor.strings), dtype=object).reshape(shape)
    dt = dtype_to_numpy(tensor.dtype)
    if len(tensor.data) != count * dt.itemsize:
        raise invalid(
            f"tensor data is {len(tensor.data)} bytes; shape {list(shape)} of "
            f"{env_pb2.DType.Name(tensor.dtype)} needs {count * dt.itemsize}"
        )
    return np.frombuffer(tensor.data, dtype=dt).reshape(shape)


def value_to_python(value: env_pb2.Value) -> Any:
    """A typed kwarg value as a plain Python value; INVALID_ARGUMENT if unset."""
    kind = value.WhichOneof("kind")
    if kind == "bool_value":
        return value.bool_value
    if kind == "int_value":
        return value.int_value
    if kind == "float_value":
        return value.float_value
    if kind == "string_value":
        return value.string_value
    if kind == "list_value":
        return [value_to_python(v) for v in value.list_value.values]
    if kind == "map_value":
        return values_to_python(value.map_value.entries)
    raise invalid("a Value has no kind set")


def values_to_python(values: Mapping[str, env_pb2.Value]) -> dict[str, Any]:
    return {key: value_to_python(v) for key, v in values.items()}


def python_to_value(obj: Any) -> env_pb2.Value:
    """A plain Python value as a Value; ValueError for what Value cannot hold."""
    if isinstance(obj, (bool, np.bool_)):
        return env_pb2.Value(bool_value=bool(obj))
    if isinstance(obj, (int, np.integer)):
        return env_pb2.Value(int_value=int(obj))
    if isinstance(obj, (float, np.floating)):
        return env_pb2.Value(float_value=float(obj))
    if isinstance(obj, str):
        return env_pb2.Value(string_value=obj)
    if isinstance(obj, (list, tuple)):
        return env_pb2.Value(list_value=env_pb2.ValueList(values=[python_to_value(v) for v in obj]))
    if isinstance(obj, Mapping):
        return env_pb2.Value(map_value=env_pb2.ValueMap(entries=python_to_values(obj)))
    raise ValueError(f"{type(obj).__name__} cannot be sent as a Value")


def python_to_values(mapping: Mapping[str, Any]) -> dict[str, env_pb2.Value]:
    return {str(key): python_to_value(v) for key, v in mapping.items()}


def representable_values(mapping: Mapping[str, Any]) -> dict[str, env_pb2.Value]:
    """The entries a Value can hold; others (None, callables, objects) are left out."""
    out = {}
    for key, v in mapping.items():
        try:
            out[str(key)] = python_to_value(v)
        except ValueError:
            continue
    return out
