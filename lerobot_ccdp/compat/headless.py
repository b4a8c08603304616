"""MuJoCo's rendering backend on a machine without a display (a server, a container, an SSH shell)."""

import os
import sys


def choose_headless_gl() -> None:
    """Set MUJOCO_GL=egl on Linux when no display is there and the user chose no backend.

    MuJoCo reads MUJOCO_GL once, when it is first imported, and its default (GLFW) needs a display:
    without one every render (lerobot-eval's videos, camera observations) raises mujoco.FatalError.
    So this runs before anything imports mujoco. A MUJOCO_GL the user set, even empty, is kept.
    """
    if not sys.platform.startswith("linux") or "MUJOCO_GL" in os.environ:
        return
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        os.environ["MUJOCO_GL"] = "egl"
