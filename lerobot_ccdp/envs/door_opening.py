"""DoorOpening: a sliding door that opens only one way (left or right); the way is hidden."""

from __future__ import annotations

import numpy as np

from lerobot_ccdp.envs.base import CCDPTaskEnv, Outcome, OutcomeKind, Waypoint
from lerobot_ccdp.envs.scene import mocap_box

HANDLE = np.array([0.0, 0.0, 0.12])
DOOR_FROM_HANDLE = np.array([0.0, 0.035, 0.0])
GRASP_RADIUS = 0.03
COMMIT_SLIDE = 0.03  # the handle must be pulled this far before the door gives away its direction
OPEN_SLIDE = 0.15
MAX_SLIDE = 0.2


class DoorOpeningEnv(CCDPTaskEnv):
    """Grasp the handle and slide the door; option 0 slides left (-x), option 1 right (+x).

    hidden_param: the direction the door opens (0 left, 1 right), equally likely. Sliding the wrong way is a
    failure as soon as the handle has been pulled `COMMIT_SLIDE` that way.
    """

    name = "DoorOpening"
    task_description = "Open the sliding door."
    n_options = 2
    env_state_names = ("handle_x", "handle_y", "handle_z")
    default_episode_steps = 150
    home = (0.0, -0.15, 0.12, 0.0)
    approach = (0.0, -0.08, 0.0)  # where the gripper comes to the handle from, relative to it: the front

    def _task_bodies_xml(self) -> str:
        door = DOOR_FROM_HANDLE + HANDLE
        return "\n".join(
            [
                mocap_box("wall_l", (-0.3, 0.06, 0.13), (0.16, 0.01, 0.13), "0.55 0.5 0.45 1"),
                mocap_box("wall_r", (0.3, 0.06, 0.13), (0.16, 0.01, 0.13), "0.55 0.5 0.45 1"),
                f'<body name="door" mocap="true" pos="{door[0]} {door[1]} {door[2]}">'
                '<geom type="box" size="0.13 0.01 0.12" rgba="0.45 0.3 0.2 1"/>'
                '<geom type="box" size="0.015 0.02 0.015" pos="0 -0.025 0" rgba="0.85 0.8 0.3 1"/></body>',
            ]
        )

    def hidden_values(self) -> list[int]:
        return [0, 1]

    def _sample_hidden(self) -> int:
        return int(self.np_random.integers(2))

    def _reset_task(self) -> None:
        self._handle0 = HANDLE + np.array([*self.jitter(2), 0.0])
        self._slide = 0.0
        self._grasp_x: float | None = None
        self._slide_at_grasp = 0.0
        self._open_dir: int | None = None
        self._place_door()

    def _place_door(self) -> None:
        self.mocap("door")[:] = self._handle_pos() + DOOR_FROM_HANDLE

    def _handle_pos(self) -> np.ndarray:
        return self._handle0 + np.array([self._slide, 0.0, 0.0])

    def _environment_state(self) -> np.ndarray:
        return self._handle_pos()

    def preference_order(self) -> list[int]:
        return [0, 1]

    def feasible(self, option: int) -> bool:
        return option == self.hidden_param

    def _update_task(self) -> Outcome | None:
        ee, handle = self.ee_pos, self._handle_pos()
        if self._grasp_x is None:
            if self.grip > 0.6 and np.linalg.norm(ee - handle) < GRASP_RADIUS:
                self._grasp_x, self._slide_at_grasp = ee[0], self._slide
            return None
        if self.grip < 0.4 or np.linalg.norm(ee[1:] - handle[1:]) > 2 * GRASP_RADIUS:
            self._grasp_x = None  # let go of the handle
            return None
        pulled = ee[0] - self._grasp_x
        if self._open_dir is None:
            if abs(pulled) < COMMIT_SLIDE:
                return None
            option = int(pulled > 0)
            if not self.feasible(option):
                return Outcome(OutcomeKind.FAILURE, option)
            self._open_dir = option
        low, high = (-MAX_SLIDE, 0.0) if self._open_dir == 0 else (0.0, MAX_SLIDE)
        self._slide = float(np.clip(self._slide_at_grasp + pulled, low, high))
        self._place_door()
        if abs(self._slide) >= OPEN_SLIDE:
            return Outcome(OutcomeKind.SUCCESS, self._open_dir, preferred=self.preferred_feasible_option())
        return None

    def _on_failure(self, option: int) -> None:
        self._grasp_x = None

    def plan(self, option: int) -> list[Waypoint]:
        x, y, z = self._handle_pos()
        direction = 1.0 if option == 1 else -1.0
        return [
            Waypoint((x + self.approach[0], y + self.approach[1], z + self.approach[2], 0.0)),
            Waypoint((x, y, z, 0.0), dwell=2),
            Waypoint((x, y, z, 1.0), dwell=3),
            Waypoint((x + direction * (OPEN_SLIDE + 0.04), y, z, 1.0), dwell=3),
        ]
