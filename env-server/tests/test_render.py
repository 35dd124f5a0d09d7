"""The optional Render RPC (feature "render"): frames through the real server have the
declared shape, show something, and are upright."""

from __future__ import annotations

import grpc
import numpy as np
import pytest

from million_env._proto import env_pb2, env_pb2_grpc
from million_env.batch import EnvBatch
from million_env.client import RemoteEnv, RemoteVectorEnv
from million_env.rendering import RendererCache, on_render_thread, render_mujoco


def _not_blank(frame: np.ndarray) -> None:
    assert frame.dtype == np.uint8
    # A blank (one-colour) or black picture has no spread of values.
    assert frame.std() > 10.0, f"frame looks blank (std {frame.std():.1f})"
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 20


def test_handshake_declares_render_and_minor_version(server_address: str) -> None:
    with grpc.insecure_channel(server_address) as channel:
        reply = env_pb2_grpc.EnvServiceStub(channel).Handshake(
            env_pb2.HandshakeRequest(client_version=env_pb2.ApiVersion(major=1, minor=1)),
            timeout=30,
        )
    assert "render" in reply.capabilities.features
    assert (reply.server_version.major, reply.server_version.minor) == (1, 1)


def test_metaworld_frame_has_the_asked_shape_and_is_upright(server_address: str) -> None:
    env = RemoteEnv(server_address, "Meta-World/MT1", env_name="reach-v3", seed=3)
    try:
        env.reset(seed=5)
        frame = env.render_frame(width=96, height=64, camera="corner")
        assert frame.shape == (64, 96, 3)
        _not_blank(frame)
        default = env.render_frame()
        assert default.shape == (224, 224, 3), "0 x 0 = the server's default size"
        np.testing.assert_array_equal(default, env.render_frame(camera="corner"))

        # The same scene rendered here, directly with MuJoCo: Meta-World's "corner" camera
        # has its image-up axis pointing down in the world, so MuJoCo's raw picture is upside
        # down and the served frame must be that picture turned by 180 degrees.
        import mujoco

        local = EnvBatch(
            "Meta-World/MT1",
            {"env_name": "reach-v3", "seed": 3},
            1,
            env_pb2.AUTORESET_MODE_DISABLED,
        )
        local.reset([], [5], {})
        base = local.envs[0].unwrapped
        camera = mujoco.mj_name2id(base.model, mujoco.mjtObj.mjOBJ_CAMERA, "corner")
        assert np.asarray(base.data.cam_xmat[camera]).reshape(3, 3)[2, 1] < 0, (
            "the corner camera's up axis points down"
        )

        def raw() -> np.ndarray:
            renderer = mujoco.Renderer(base.model, height=64, width=96)
            renderer.update_scene(base.data, camera=camera)
            picture = renderer.render().copy()
            renderer.close()
            return picture

        direct = on_render_thread(raw)
        np.testing.assert_allclose(frame, direct[::-1, ::-1], atol=2)
        assert np.abs(frame.astype(int) - direct.astype(int)).mean() > 5, (
            "the raw picture is not symmetric, so the turn is visible"
        )
        local.close()
    finally:
        env.close()


def test_upright_camera_is_not_turned() -> None:
    # A camera whose up axis points up (behindGripper) is served as MuJoCo draws it; all
    # four of Meta-World's corner cameras point theirs down and are turned.
    import gymnasium as gym
    import metaworld  # noqa: F401
    import mujoco

    env = gym.make("Meta-World/MT1", env_name="reach-v3", seed=3, disable_env_checker=True)
    env.reset(seed=1)
    base = env.unwrapped
    cache = RendererCache()

    def both() -> tuple[np.ndarray, np.ndarray]:
        served = render_mujoco(base.model, base.data, 64, 48, "behindGripper", cache)
        renderer = cache.renderer(base.model, 64, 48)
        renderer.update_scene(base.data, camera="behindGripper")
        return served, renderer.render().copy()

    served, direct = on_render_thread(both)
    np.testing.assert_array_equal(served, direct)
    for name in ("corner", "corner2", "corner3", "corner4"):
        camera = mujoco.mj_name2id(base.model, mujoco.mjtObj.mjOBJ_CAMERA, name)
        assert np.asarray(base.data.cam_xmat[camera]).reshape(3, 3)[2, 1] < 0, name
    on_render_thread(cache.close)
    env.close()


def test_million_env_renders_its_metaworld_scene_and_pointgoal_a_drawing(
    server_address: str,
) -> None:
    envs = RemoteVectorEnv(server_address, "million/ML1-train", 2, task="reach-v3")
    try:
        envs.reset(seed=1)
        frames = envs.render_frames(width=80, height=60)
        assert frames.shape == (2, 60, 80, 3)
        for f in frames:
            _not_blank(f)
        one = envs.render_frames([1], width=80, height=60)
        np.testing.assert_array_equal(one[0], frames[1])
        # Rendering changes nothing: the next step is the same as without it.
        obs, *_ = envs.step(np.zeros((2, 4), dtype=np.float32))
        assert np.all(np.isfinite(obs["state"]))
    finally:
        envs.close()

    point = RemoteEnv(server_address, "million/PointGoal")
    try:
        _, info = point.reset(seed=2)
        frame = point.render_frame(width=100, height=100)
        assert frame.shape == (100, 100, 3)
        # The goal's green disc lies where the goal is (north = up, east = right).
        goal = np.asarray(info["goal"])
        green = np.argwhere((frame[:, :, 1] > 150) & (frame[:, :, 0] < 100))
        assert len(green) > 0
        row, col = green.mean(axis=0)
        assert np.sign(col - 50) == np.sign(round(goal[0], 3)) or abs(goal[0]) < 1e-6
        assert np.sign(50 - row) == np.sign(round(goal[1], 3)) or abs(goal[1]) < 1e-6
        with pytest.raises(grpc.RpcError) as err:
            point.render_frame(camera="corner")
        assert err.value.code() == grpc.StatusCode.INVALID_ARGUMENT
    finally:
        point.close()


def test_render_errors_are_clear(server_address: str) -> None:
    with grpc.insecure_channel(server_address) as channel:
        stub = env_pb2_grpc.EnvServiceStub(channel)
        with pytest.raises(grpc.RpcError) as err:
            stub.Render(env_pb2.RenderRequest(handle="nope"), timeout=30)
        assert err.value.code() == grpc.StatusCode.NOT_FOUND
        made = stub.Make(env_pb2.MakeRequest(env_id="CartPole-v1", num_envs=1), timeout=60)
        try:
            with pytest.raises(grpc.RpcError) as err:
                stub.Render(env_pb2.RenderRequest(handle=made.handle), timeout=30)
            assert err.value.code() == grpc.StatusCode.FAILED_PRECONDITION, "before reset"
            stub.Reset(env_pb2.ResetRequest(handle=made.handle), timeout=30)
            with pytest.raises(grpc.RpcError) as err:
                stub.Render(env_pb2.RenderRequest(handle=made.handle), timeout=30)
            assert err.value.code() == grpc.StatusCode.UNIMPLEMENTED
            assert "render_mode" in err.value.details()
            with pytest.raises(grpc.RpcError) as err:
                stub.Render(env_pb2.RenderRequest(handle=made.handle, width=5000), timeout=30)
            assert err.value.code() == grpc.StatusCode.INVALID_ARGUMENT
            # The handle still works after failed renders.
            stub.Step(
                env_pb2.StepRequest(
                    handle=made.handle,
                    action=env_pb2.Tensor(
                        dtype=env_pb2.DTYPE_INT64, shape=[1], data=np.int64(0).tobytes()
                    ),
                ),
                timeout=30,
            )
        finally:
            stub.Close(env_pb2.CloseRequest(handle=made.handle), timeout=30)
