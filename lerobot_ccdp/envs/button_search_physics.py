"""ButtonSearch on the Franka Panda with contact physics: each button is a spring-loaded cap on a slide joint.

Same options, hidden parameter, observations and metrics as the lite task (`button_search.py`). A button
counts as pressed when the simulation has pushed its cap `PRESS_DEPTH` into its housing; whether it was the
live one is the hidden parameter, as a light behind the panel would tell (the one piece left to a rule: wiring
has no physics here). The gripper presses with closed fingers (open, the 2F-85's fingers straddle the cap).
"""

from __future__ import annotations

import numpy as np

from lerobot_ccdp.envs.base import Outcome, OutcomeKind
from lerobot_ccdp.envs.button_search import BUTTONS_XY, ButtonSearchEnv
from lerobot_ccdp.envs.panda import PandaArm

TRAVEL = 0.01  # how far a cap can be pushed in
# pushed this far, a button is pressed; it can be pressed again once back above half of it
PRESS_DEPTH = 0.004


class ButtonSearchPhysicsEnv(ButtonSearchEnv):
    """The lite task's press rule replaced by the simulation (see the module docstring)."""

    robot_class = PandaArm
    # Closed fingers, the pinch point 4 cm up: the pads' lower edges (1.8 cm below it) push the cap 8 mm in.
    press_grip, press_z = 1.0, 0.04

    def _task_bodies_xml(self) -> str:
        return "\n".join(
            f"""
    <body name="button_{i}" pos="{x} {y} 0">
      <geom name="housing_{i}" type="cylinder" pos="0 0 0.005" size="0.03 0.005" rgba="0.3 0.3 0.32 1"/>
      <body name="cap_{i}" pos="0 0 0.022">
        <joint name="cap_{i}" type="slide" axis="0 0 1" range="{-TRAVEL} 0" stiffness="300" damping="3"
               solreflimit="0.005 1"/>
        <geom name="cap_{i}" type="cylinder" size="0.02 0.008" mass="0.02" rgba="0.8 0.15 0.15 1"/>
      </body>
    </body>"""
            for i, (x, y) in enumerate(BUTTONS_XY)
        )

    def _reset_task(self) -> None:
        self._buttons = BUTTONS_XY + self.jitter(*BUTTONS_XY.shape)
        for i, xy in enumerate(self._buttons):
            self.model.body_pos[self.model.body(f"button_{i}").id][:2] = xy
        self._caps = np.array([self.model.joint(f"cap_{i}").qposadr[0] for i in range(self.n_options)])
        self._armed = np.ones(self.n_options, dtype=bool)  # released since its last press

    def cap_depths(self) -> np.ndarray:
        """How far each cap is pushed in (metres)."""
        return -self.data.qpos[self._caps]

    def _update_task(self) -> Outcome | None:
        depth = self.cap_depths()
        self._armed |= depth < PRESS_DEPTH / 2
        pressed = np.flatnonzero(self._armed & (depth >= PRESS_DEPTH))
        if pressed.size == 0:
            return None
        option = int(pressed[np.argmax(depth[pressed])])
        self._armed[option] = False
        if not self.feasible(option):
            return Outcome(OutcomeKind.FAILURE, option)
        return Outcome(OutcomeKind.SUCCESS, option, preferred=self.preferred_feasible_option())
