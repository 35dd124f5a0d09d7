"""Tensors, values, spaces and actions to and from their proto messages."""

from __future__ import annotations

import grpc
import numpy as np
import pytest
from gymnasium import spaces

from million_env._proto import env_pb2
from million_env.errors import ApiError
from million_env.info_fields import InfoField, decode_info, encode_info
from million_env.spaces import (
    decode_actions,
    decode_observations,
    encode_observations,
    space_from_proto,
    space_to_proto,
)
from million_env.tensors import (
    decode_tensor,
    encode_tensor,
    python_to_value,
    representable_values,
    value_to_python,
)


@pytest.mark.parametrize(
    "dtype", ["float32", "float64", "int8", "int16", "int32", "int64", "uint8", "bool"]
)
def test_tensor_round_trip_is_exact(dtype: str) -> None:
    array = (
        (np.arange(24).reshape(2, 3, 4) % 2 == 1)
        if dtype == "bool"
        else (np.arange(24).reshape(2, 3, 4).astype(dtype))
    )
    message = encode_tensor(array)
    assert list(message.shape) == [2, 3, 4]
    assert message.data == array.astype(array.dtype.newbyteorder("<")).tobytes()
    back = decode_tensor(message)
    assert back.dtype == array.dtype and np.array_equal(back, array)


def test_big_endian_input_is_sent_little_endian() -> None:
    array = np.array([1.5, -2.0], dtype=">f8")
    message = encode_tensor(array)
    assert message.dtype == env_pb2.DTYPE_FLOAT64
    assert message.data == np.array([1.5, -2.0], dtype="<f8").tobytes()


def test_string_tensor_round_trip() -> None:
    array = np.array([["pick", "up"], ["the", "cup"]], dtype=object)
    message = encode_tensor(array)
    assert message.dtype == env_pb2.DTYPE_STRING and not message.data
    assert decode_tensor(message).tolist() == array.tolist()


def test_tensor_data_length_checked() -> None:
    bad = env_pb2.Tensor(dtype=env_pb2.DTYPE_FLOAT32, shape=[2], data=b"\x00" * 7)
    with pytest.raises(ApiError) as caught:
        decode_tensor(bad)
    assert caught.value.code == grpc.StatusCode.INVALID_ARGUMENT


def test_values_round_trip() -> None:
    nested = {"a": True, "b": 3, "c": 2.5, "d": "x", "e": [1, "y", [False]], "f": {"g": -1}}
    for key, value in nested.items():
        assert value_to_python(python_to_value(value)) == value, key
    assert isinstance(value_to_python(python_to_value(True)), bool)
    with pytest.raises(ApiError):
        value_to_python(env_pb2.Value())
    assert set(representable_values({"ok": 1, "none": None, "fn": len})) == {"ok"}


@pytest.mark.parametrize(
    "space",
    [
        spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32),
        spaces.Box(low=np.array([-np.inf, 0.0]), high=np.array([np.inf, 2.0]), dtype=np.float64),
        spaces.Box(0, 255, shape=(3, 2), dtype=np.uint8),
        spaces.Discrete(5, start=-2),
        spaces.MultiBinary(6),
        spaces.MultiDiscrete(np.array([[3, 4], [5, 6]]), start=np.array([[0, 1], [2, 3]])),
        spaces.Dict({"pos": spaces.Box(-1, 1, (2,)), "id": spaces.Discrete(3)}),
    ],
)
def test_space_round_trip(space: spaces.Space) -> None:
    back = space_from_proto(space_to_proto(space))
    if isinstance(space, spaces.MultiDiscrete):
        assert np.array_equal(back.nvec, space.nvec) and np.array_equal(back.start, space.start)
    else:
        assert back == space


def test_unsupported_space_rejected() -> None:
    from million_env.spaces import UnsupportedSpaceError

    with pytest.raises(UnsupportedSpaceError, match="Tuple"):
        space_to_proto(spaces.Tuple((spaces.Discrete(2),)))


def test_dict_observations_batched_in_space_order() -> None:
    space = spaces.Dict({"pos": spaces.Box(-1, 1, (2,)), "id": spaces.Discrete(3)})
    rows = [{"pos": np.array([0.1, 0.2], np.float32), "id": 2}, space.sample()]
    message = encode_observations(space, rows)
    assert [e.name for e in message.dict.entries] == list(space.spaces)
    decoded = decode_observations(message)
    assert decoded["pos"].shape == (2, 2) and decoded["id"].dtype == np.int64
    assert decoded["id"][0] == 2


def test_actions_validated() -> None:
    box = spaces.Box(-1, 1, (4,), dtype=np.float32)
    good = np.zeros((3, 4), np.float32)
    assert decode_actions(box, encode_tensor(good), 3).flags.writeable
    for bad, what in [
        (np.zeros((3, 4), np.float64), "dtype"),
        (np.zeros((2, 4), np.float32), "shape"),
        (np.full((3, 4), np.nan, np.float32), "finite"),
    ]:
        with pytest.raises(ApiError, match=what) as caught:
            decode_actions(box, encode_tensor(bad), 3)
        assert caught.value.code == grpc.StatusCode.INVALID_ARGUMENT
    with pytest.raises(ApiError, match="outside"):
        decode_actions(spaces.Discrete(2), encode_tensor(np.array([0, 2])), 2)
    with pytest.raises(ApiError, match="0 or 1"):
        decode_actions(spaces.MultiBinary(2), encode_tensor(np.array([[0, 2]], np.int8)), 1)


def test_info_fields_encoded_with_presence() -> None:
    fields = (
        InfoField("success", "float64"),
        InfoField("task_name", "str"),
        InfoField("goal", "float32", (3,)),
    )
    infos = [{"success": 1.0, "task_name": "reach-v3", "extra": object()}, {"goal": [1, 2, 3]}]
    message = encode_info(fields, infos)
    assert [e.name for e in message.entries] == ["success", "task_name", "goal"]
    decoded = decode_info(message)
    assert decoded["success"].tolist() == [1.0, 0.0]
    assert decoded["_success"].tolist() == [True, False]
    assert decoded["task_name"].tolist() == ["reach-v3", ""]
    assert decoded["goal"].dtype == np.float32 and decoded["goal"][1].tolist() == [1, 2, 3]
    assert "extra" not in decoded
    for wrong in ({"goal": [1, 2]}, {"success": [1.0, 0.0]}):
        with pytest.raises(ApiError) as caught:
            encode_info(fields, [wrong])
        assert caught.value.code == grpc.StatusCode.INTERNAL
