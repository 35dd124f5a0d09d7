"""MILLION environment server: Gymnasium and Meta-World v3 environments over gRPC."""

import os

# Frames of MuJoCo scenes (the Render RPC) are drawn headless; MuJoCo reads this when it
# is first imported. A value set by the user wins (e.g. "osmesa" where EGL is missing).
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
