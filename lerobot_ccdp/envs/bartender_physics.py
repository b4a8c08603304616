"""Bartender on the Franka Panda with contact physics: the gripper holds a real bottle over real cups.

Same options, hidden parameter, observations and metrics as the lite task (`bartender.py`). The bottle is a
free body held by the 2F-85's friction grasp and the cups are free bodies on the table, so a clumsy move
knocks a cup over or drops the bottle. The pour is the one piece left to a rule, as liquid is not simulated at
this cost: holding the bottle `POUR_HEIGHT` over a cup for `POUR_STEPS` steps pours; whether the cup could
take the drink is the hidden parameter.
"""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_ccdp.envs.bartender import CUPS_XY, EMPTY_Z, FULL_Z, BartenderEnv
from lerobot_ccdp.envs.panda import PandaArm

BOTTLE_RADIUS, BOTTLE_HALF_HEIGHT = 0.015, 0.045
BOTTLE_ABOVE_PINCH = 0.03  # the bottle's centre above the pinch point where the gripper takes it
# physics steps (0.3 s) the gripper closes on the bottle at reset, the bottle held still
GRASP_SETTLE_STEPS = 150


class BartenderPhysicsEnv(BartenderEnv):
    """The lite task with a bottle and cups that are bodies in the simulation (see the module docstring)."""

    robot_class = PandaArm
    pour_z = 0.09  # the held bottle's bottom clears the cups' rims by about 3 cm

    def _task_bodies_xml(self) -> str:
        glass, drink = "0.8 0.85 0.9 0.5", "0.9 0.6 0.1 1"
        cups = "\n".join(
            f"""
    <body name="cup_{i}" pos="{x} {y} 0.02"><freejoint name="cup_{i}"/>
      <geom name="cup_{i}" type="cylinder" size="0.025 0.02" mass="0.1" rgba="{glass}"/>
      <body name="drink_{i}" pos="0 0 {EMPTY_Z - 0.02}">
        <geom type="cylinder" size="0.02 0.016" rgba="{drink}" contype="0" conaffinity="0" mass="0.001"/>
      </body>
    </body>"""
            for i, (x, y) in enumerate(CUPS_XY)
        )
        bottle = f"""
    <body name="bottle" pos="0 0 0.5"><freejoint name="bottle"/>
      <geom name="bottle" type="cylinder" size="{BOTTLE_RADIUS} {BOTTLE_HALF_HEIGHT}" mass="0.15" friction="1"
            rgba="0.2 0.5 0.25 1"/>
    </body>"""
        return cups + bottle

    def _reset_task(self) -> None:
        self._cups = CUPS_XY + self.jitter(*CUPS_XY.shape)
        for i, xy in enumerate(self._cups):
            self.place_free_body(f"cup_{i}", (*xy, 0.02))
        self._filled = np.zeros(len(CUPS_XY), dtype=bool)
        self._pouring_into, self._pour_steps = -1, 0
        self._grasp_bottle()
        self._show_drinks()

    def bottle_position(self) -> np.ndarray:
        return self.free_pose("bottle")[:3].copy()

    def _grasp_bottle(self) -> None:
        """Put the bottle between the fingers and let the gripper (commanded closed at home) close on it."""
        position = self.ee_pos + [0.0, 0.0, BOTTLE_ABOVE_PINCH]
        for _ in range(GRASP_SETTLE_STEPS):
            self.place_free_body("bottle", position)
            mujoco.mj_step(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)

    def _show_drinks(self) -> None:
        """A filled cup shows its drink (the pour is by rule; its look follows the cup)."""
        for i, filled in enumerate(self._filled):
            self.model.body_pos[self.model.body(f"drink_{i}").id][2] = (FULL_Z if filled else EMPTY_Z) - 0.02

    def _follow_bottle(self) -> None:
        """The bottle is a body the gripper holds: nothing to move."""

    def _begin_attempt(self) -> None:
        super()._begin_attempt()
        self._bottle_at_start = self.free_pose("bottle").copy()

    def _update_task(self):
        # where they stand now
        self._cups = np.array([self.free_pose(f"cup_{i}")[:2] for i in range(len(CUPS_XY))])
        return super()._update_task()

    def _on_failure(self, option: int) -> None:
        """The robot is back where the attempt began, and the bottle with it, in its grasp."""
        super()._on_failure(option)
        self.place_free_body("bottle", self._bottle_at_start[:3], self._bottle_at_start[3:])
