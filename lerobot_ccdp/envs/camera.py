"""Camera observations of the tasks (obs_type `pixels_agent_pos`): small RGB frames rendered each control
step."""

from __future__ import annotations

import mujoco
import numpy as np


class CameraRenderer:
    """Renders named scene cameras at the observation size, without shadows or reflections.

    Those two effects cost about two thirds of a frame in software OpenGL (what a CPU machine has) and show
    the policy nothing it needs. The renderer is made on first use, so a state-only env never opens a GL
    context.
    """

    def __init__(self, width: int, height: int):
        self.width, self.height = width, height
        self._renderer: mujoco.Renderer | None = None

    def render(self, model: mujoco.MjModel, data: mujoco.MjData, camera: str) -> np.ndarray:
        """(height, width, 3) uint8 image of `camera`."""
        if self._renderer is None:
            self._renderer = mujoco.Renderer(model, height=self.height, width=self.width)
        self._renderer.update_scene(data, camera=camera)
        flags = self._renderer.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
