"""RGB frames of environments, for the optional `Render` RPC (feature "render").

Frames are uint8 ``[height, width, 3]`` with row 0 at the top. How an environment is
drawn, in this order:

1. its unwrapped env has ``render_rgb(width, height, camera, cache)`` (the MILLION
   protocol envs, the Meta-World split envs): it draws itself;
2. it is a MuJoCo env (``model`` and ``data`` of the unwrapped env): MuJoCo's
   offscreen renderer, headless with ``MUJOCO_GL=egl`` (set by default on import of
   `million_env`);
3. it was made with ``render_mode="rgb_array"``: its own ``render()``, resized;
4. otherwise `UNIMPLEMENTED`.

MuJoCo renderers own a GL context, which lives on one thread: every frame is drawn
on the single render thread of this module (`on_render_thread`), and a batch's
renderers are kept in its `RendererCache` and freed there when the batch closes.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from million_env.errors import invalid, unimplemented

T = TypeVar("T")

DEFAULT_SIZE = 224
MAX_SIZE = 1024
#: The default view of Meta-World scenes: Meta-World's own corner camera (turned upright).
METAWORLD_DEFAULT_CAMERA = "corner"

Frame = npt.NDArray[np.uint8]

_RENDER_THREAD: ThreadPoolExecutor | None = None
_RENDER_THREAD_LOCK = threading.Lock()


def on_render_thread(call: Callable[[], T]) -> T:
    """Runs `call` on the one thread that owns every GL context, and waits for it."""
    global _RENDER_THREAD
    with _RENDER_THREAD_LOCK:
        if _RENDER_THREAD is None:
            _RENDER_THREAD = ThreadPoolExecutor(max_workers=1, thread_name_prefix="render")
        executor = _RENDER_THREAD
    if threading.current_thread().name.startswith("render"):
        return call()
    return executor.submit(call).result()


def frame_size(width: int, height: int) -> tuple[int, int]:
    """(width, height) with 0 meaning the default; INVALID_ARGUMENT above MAX_SIZE."""
    width = width or DEFAULT_SIZE
    height = height or DEFAULT_SIZE
    if width > MAX_SIZE or height > MAX_SIZE:
        raise invalid(
            f"frames are at most {MAX_SIZE} x {MAX_SIZE} pixels, asked {width} x {height}"
        )
    return width, height


class RendererCache:
    """MuJoCo renderers of one batch, by (model, size); used on the render thread only."""

    def __init__(self) -> None:
        self._renderers: dict[tuple[int, int, int], Any] = {}

    def renderer(self, model: Any, width: int, height: int) -> Any:
        key = (id(model), width, height)
        renderer = self._renderers.get(key)
        if renderer is None:
            import mujoco

            # The offscreen buffer must hold the frame; the model's default is 640 x 480.
            model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
            model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)
            try:
                renderer = mujoco.Renderer(model, height=height, width=width)
            except Exception as err:
                raise unimplemented(
                    f"MuJoCo cannot render here ({type(err).__name__}: {err}); a headless "
                    "server needs MUJOCO_GL=egl (libEGL) or MUJOCO_GL=osmesa"
                ) from err
            # The renderer keeps `model` alive, so its id stays unique in this cache.
            self._renderers[key] = renderer
        return renderer

    def close(self) -> None:
        for renderer in self._renderers.values():
            try:
                renderer.close()
            except Exception:  # freeing a GL context is best effort
                pass
        self._renderers.clear()


def _upside_down(model: Any, data: Any, camera_id: int) -> bool:
    """True when the camera's image-up axis points down in the world (a camera rolled
    by 180 degrees, like Meta-World's "corner"): its picture must be turned around."""
    if camera_id < 0:
        return False
    up_axis = np.asarray(data.cam_xmat[camera_id]).reshape(3, 3)[:, 1]
    return bool(up_axis[2] < 0.0)


def render_mujoco(
    model: Any, data: Any, width: int, height: int, camera: str, cache: RendererCache
) -> Frame:
    """One upright frame of a MuJoCo scene; `camera` "" = the free camera."""
    import mujoco

    if camera:
        camera_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if camera_id < 0:
            names = [model.camera(i).name for i in range(model.ncam)]
            raise invalid(f"no camera {camera!r} in this scene; it has {names}")
    else:
        camera_id = -1
    renderer = cache.renderer(model, width, height)
    renderer.update_scene(data, camera=camera_id)
    frame = np.asarray(renderer.render(), dtype=np.uint8)
    if _upside_down(model, data, camera_id):
        frame = frame[::-1, ::-1]
    return np.ascontiguousarray(frame)


def render_metaworld(env: Any, width: int, height: int, camera: str, cache: RendererCache) -> Frame:
    """A Meta-World (SawyerXYZEnv) scene; `camera` "" = METAWORLD_DEFAULT_CAMERA."""
    base = env.unwrapped
    return render_mujoco(
        base.model, base.data, width, height, camera or METAWORLD_DEFAULT_CAMERA, cache
    )


def _resize(frame: npt.NDArray[Any], width: int, height: int) -> Frame:
    from PIL import Image

    image = np.asarray(frame)
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise unimplemented(f"the env's render() gave an array of shape {image.shape}, not RGB")
    image = image[:, :, :3].astype(np.uint8, copy=False)
    if image.shape[:2] == (height, width):
        return np.ascontiguousarray(image)
    resized = Image.fromarray(image).resize((width, height), Image.Resampling.BILINEAR)
    return np.asarray(resized, dtype=np.uint8)


def render_env(env: Any, width: int, height: int, camera: str, cache: RendererCache) -> Frame:
    """One frame of `env` in its current state (see the module doc for how)."""
    base = env.unwrapped
    own = getattr(base, "render_rgb", None)
    if callable(own):
        return own(width, height, camera, cache)
    if _is_metaworld(base):
        return render_metaworld(base, width, height, camera, cache)
    model, data = getattr(base, "model", None), getattr(base, "data", None)
    if model is not None and data is not None and type(model).__name__ == "MjModel":
        return render_mujoco(model, data, width, height, camera, cache)
    if getattr(env, "render_mode", None) == "rgb_array":
        if camera:
            raise invalid("this env has no named cameras; leave camera empty")
        return _resize(env.render(), width, height)
    raise unimplemented(
        f"{type(base).__name__} cannot render: it is no MuJoCo env and was not made with "
        "render_mode='rgb_array'"
    )


def _is_metaworld(base: Any) -> bool:
    try:
        from metaworld.sawyer_xyz_env import SawyerXYZEnv
    except ImportError:
        return False
    return isinstance(base, SawyerXYZEnv)


# ---------------------------------------------------------------------------- drawing


def blank(width: int, height: int, rgb: tuple[int, int, int] = (255, 255, 255)) -> Frame:
    frame = np.empty((height, width, 3), dtype=np.uint8)
    frame[:] = rgb
    return frame


def draw_disc(
    frame: Frame, cx: float, cy: float, radius: float, rgb: tuple[int, int, int], ring: bool = False
) -> None:
    """A filled disc (or a ring 2 px wide) centred at pixel (cx, cy)."""
    height, width = frame.shape[:2]
    ys, xs = np.ogrid[:height, :width]
    dist = np.hypot(xs - cx, ys - cy)
    mask = (dist <= radius) & (dist >= radius - 2.0) if ring else dist <= radius
    frame[mask] = rgb
