"""DoorOpening on the Franka Panda with contact physics: the door is a sliding body behind a one-way stop.

Same options, hidden parameter, observations and metrics as the lite task (`door_opening.py`). The door slides
on a joint whose travel the hidden parameter limits to one side (the stop of a one-way latch), so pushing it
the wrong way moves nothing. The gripper closes on the handle from above, its fingers on the handle's sides,
and slides it. The env only reads what happened: once the arm has tried to move the handle `COMMIT_SLIDE` one
way and the door has not given way, the attempt failed; the task succeeds when the door has slid `OPEN_SLIDE`.
"""

from __future__ import annotations

import numpy as np

from lerobot_ccdp.envs.base import Outcome, OutcomeKind
from lerobot_ccdp.envs.door_opening import COMMIT_SLIDE, HANDLE, MAX_SLIDE, OPEN_SLIDE, DoorOpeningEnv
from lerobot_ccdp.envs.panda import PandaArm

# the handle stands out of the door's front face, clear of the gripper
HANDLE_FROM_DOOR = np.array([0.0, -0.07, 0.0])
GRASPED, RELEASED = 0.3, 0.15  # measured gripper closure: closed on the handle, open again
STUCK = 0.005  # a door that moved less than this under the push did not give way


class DoorOpeningPhysicsEnv(DoorOpeningEnv):
    """The lite task's rules replaced by the simulation (see the module docstring)."""

    robot_class = PandaArm
    approach = (0.0, 0.0, 0.08)  # from above: the fingers close on the handle's sides

    def _task_bodies_xml(self) -> str:
        door = HANDLE - HANDLE_FROM_DOOR
        wall_y = door[1] + 0.04  # behind the door, clear of it whatever the layout noise
        return f"""
    <geom name="wall_l" type="box" pos="-0.31 {wall_y} 0.13" size="0.16 0.01 0.13" rgba="0.55 0.5 0.45 1"/>
    <geom name="wall_r" type="box" pos="0.31 {wall_y} 0.13" size="0.16 0.01 0.13" rgba="0.55 0.5 0.45 1"/>
    <body name="door" pos="{door[0]} {door[1]} {door[2]}">
      <joint name="door" type="slide" axis="1 0 0" range="{-MAX_SLIDE} {MAX_SLIDE}" damping="5"
             frictionloss="1" solreflimit="0.005 1"/>
      <geom name="panel" type="box" size="0.13 0.01 0.11" rgba="0.45 0.3 0.2 1"/>
      <geom name="neck" type="box" pos="0 -0.03 0" size="0.008 0.02 0.008" rgba="0.85 0.8 0.3 1"/>
      <geom name="handle" type="box" pos="{HANDLE_FROM_DOOR[0]} {HANDLE_FROM_DOOR[1]} {HANDLE_FROM_DOOR[2]}"
            size="0.015 0.02 0.015" friction="1" rgba="0.85 0.8 0.3 1"/>
    </body>"""

    def _reset_task(self) -> None:
        door = self.model.joint("door")
        self._door_qpos = door.qposadr[0]
        self.model.body_pos[self.model.body("door").id] = HANDLE - HANDLE_FROM_DOOR + [*self.jitter(2), 0.0]
        self.data.qpos[self._door_qpos] = 0.0
        self._grasp_x: float | None = None
        self._open_dir: int | None = None

    def _apply_hidden(self) -> None:
        """The stop: the door slides only toward the side it opens to (0 left, 1 right)."""
        travel = (-MAX_SLIDE, 0.0) if self.hidden_param == 0 else (0.0, MAX_SLIDE)
        self.model.jnt_range[self.model.joint("door").id] = travel

    @property
    def slide(self) -> float:
        return float(self.data.qpos[self._door_qpos])

    def _handle_pos(self) -> np.ndarray:
        return self.data.geom_xpos[self.model.geom("handle").id].copy()

    def _update_task(self) -> Outcome | None:
        pinch, grip = self.ee_pos, self.grip
        if self._grasp_x is None:
            if grip > GRASPED and np.abs(pinch - self._handle_pos()).max() < 0.02:
                self._grasp_x = pinch[0]
            return None
        pushed = self.robot.target[0] - self._grasp_x
        if self._open_dir is None and abs(pushed) >= COMMIT_SLIDE:
            option = int(pushed > 0)
            # the arm pushed the handle and the door did not give way
            if self.slide * np.sign(pushed) < STUCK:
                self._grasp_x = None
                return Outcome(OutcomeKind.FAILURE, option)
            self._open_dir = option
        if abs(self.slide) >= OPEN_SLIDE:
            return Outcome(
                OutcomeKind.SUCCESS, int(self.slide > 0), preferred=self.preferred_feasible_option()
            )
        if grip < RELEASED and self._open_dir is None and abs(pushed) < COMMIT_SLIDE / 2:
            self._grasp_x = None  # let go before trying either way
        return None
