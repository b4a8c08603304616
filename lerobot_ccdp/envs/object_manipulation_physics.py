"""ObjectManipulation on the Franka Panda with contact physics: the box's mass decides whether the grasp
holds.

Same options, hidden parameter, preferences, observations and expert plans as the lite task
(`object_manipulation.py`), but the box is a free body on the table and nothing is scripted: the 2F-85 closes
with a limited force, so friction lifts the light box (0.2 kg) and the heavy one (2.5 kg) slips out; pushing
slides either along the table. The env only reads what happened: a pick fails when the gripper has risen
`LIFT` above where it closed on the box and the box has not followed, and the task succeeds when the box rests
on the target (after a pick, once the gripper has let go).
"""

from __future__ import annotations

import numpy as np

from lerobot_ccdp.envs.base import Outcome, OutcomeKind
from lerobot_ccdp.envs.object_manipulation import BOX, HALF, PICK, PUSH, ObjectManipulationEnv
from lerobot_ccdp.envs.panda import PandaArm

MASS = {0: 0.2, 1: 2.5}  # kg, light and heavy
LIFT = 0.04  # how far the closed gripper rises before the pick is judged
GRASPED, RELEASED = 0.4, 0.2  # measured gripper closure: closed on the box, open again
RESTING = HALF + 0.005  # the box's centre height when it lies on the table


class ObjectManipulationPhysicsEnv(ObjectManipulationEnv):
    """The lite task's rules replaced by the simulation (see the module docstring)."""

    robot_class = PandaArm
    push_grip = 1.0  # an open 2F-85 would straddle the box; pushing is done with closed fingers

    def _task_bodies_xml(self) -> str:
        return f"""
    <body name="target" mocap="true" pos="0 0.2 0.001">
      <geom type="cylinder" size="0.035 0.001" rgba="0.2 0.7 0.3 1" contype="0" conaffinity="0"/>
    </body>
    <body name="box" pos="{BOX[0]} {BOX[1]} {HALF}">
      <freejoint name="box"/>
      <geom name="box" type="box" size="{HALF} {HALF} {HALF}" mass="{MASS[0]}" friction="0.8"
            rgba="0.2 0.35 0.8 1"/>
    </body>"""

    def box_position(self) -> np.ndarray:
        return self.free_pose("box")[:3].copy()

    def _reset_task(self) -> None:
        self._target = BOX[:2] + np.array([0.0, 0.2]) + self.jitter(2)
        self.mocap("target")[:2] = self._target
        self.place_free_body("box", (*(BOX[:2] + self.jitter(2)), HALF))
        # (pinch z, box z) when the gripper closed on the box
        self._closed_at: tuple[float, float] | None = None
        self._lifted = False

    def _apply_hidden(self) -> None:
        box = self.model.body("box").id
        scale = MASS[self.hidden_param] / self.model.body_mass[box]
        self.model.body_mass[box] *= scale
        self.model.body_inertia[box] *= scale

    def _environment_state(self) -> np.ndarray:
        return np.concatenate([self.box_position(), self._target])

    def _at_target(self) -> bool:
        box = self.box_position()
        return bool(np.linalg.norm(box[:2] - self._target) < 0.03 and box[2] < RESTING)

    def _update_task(self) -> Outcome | None:
        box, pinch, grip = self.box_position(), self.ee_pos, self.grip
        if grip < RELEASED:
            self._closed_at = None
        elif self._closed_at is None and grip > GRASPED and np.abs(pinch - box).max() < HALF:
            self._closed_at = (pinch[2], box[2])
        if self._closed_at is not None and not self._lifted and pinch[2] > self._closed_at[0] + LIFT:
            if box[2] - self._closed_at[1] < LIFT / 2:  # the box did not follow the gripper: it slipped
                self._closed_at = None
                return Outcome(OutcomeKind.FAILURE, PICK)
            self._lifted = True
        if self._at_target() and (grip < RELEASED or not self._lifted):
            option = PICK if self._lifted else PUSH
            return Outcome(OutcomeKind.SUCCESS, option, preferred=self.preferred_feasible_option())
        return None
