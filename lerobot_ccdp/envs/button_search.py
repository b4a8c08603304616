"""ButtonSearch: four buttons on the table, only one of them live; which one is hidden."""

from __future__ import annotations

import numpy as np

from lerobot_ccdp.envs.base import CCDPTaskEnv, Outcome, OutcomeKind, Waypoint
from lerobot_ccdp.envs.scene import mocap_cylinder

BUTTONS_XY = np.array([[-0.18, 0.1], [-0.06, 0.1], [0.06, 0.1], [0.18, 0.1]])
PRESS_RADIUS = 0.03
PRESS_HEIGHT = 0.03  # the end effector must come this low over a button to press it


class ButtonSearchEnv(CCDPTaskEnv):
    """Press the live button; option i presses button i. Pressing a dead button is a failure.

    hidden_param: index of the live button, uniform. The demonstrator has no preference beyond reaching the
    live button; the reference order (used by the no-repeat oracle) is nearest first from the attempt's start.
    """

    name = "ButtonSearch"
    task_description = "Find and press the live button."
    n_options = len(BUTTONS_XY)
    env_state_names = tuple(f"button{i}_{c}" for i in range(len(BUTTONS_XY)) for c in "xy")
    default_episode_steps = 200
    home = (-0.26, -0.12, 0.1, 0.0)
    press_grip, press_z = 0.0, 0.015  # gripper closure and end-effector height while pressing

    def _task_bodies_xml(self) -> str:
        return "\n".join(
            mocap_cylinder(f"button_{i}", (x, y, 0.008), 0.025, 0.008, "0.8 0.15 0.15 1")
            for i, (x, y) in enumerate(BUTTONS_XY)
        )

    def hidden_values(self) -> list[int]:
        return list(range(self.n_options))

    def _sample_hidden(self) -> int:
        return int(self.np_random.integers(self.n_options))

    def _reset_task(self) -> None:
        self._buttons = BUTTONS_XY + self.jitter(*BUTTONS_XY.shape)
        for i, xy in enumerate(self._buttons):
            self.mocap(f"button_{i}")[:] = (*xy, 0.008)

    def _environment_state(self) -> np.ndarray:
        return self._buttons.ravel()

    def preference_order(self) -> list[int]:
        distances = np.linalg.norm(self._buttons - self.attempt_start_pose[:2], axis=1)
        return [int(i) for i in np.argsort(distances, kind="stable")]

    def feasible(self, option: int) -> bool:
        return option == self.hidden_param

    def _update_task(self) -> Outcome | None:
        ee = self.ee_pos
        if ee[2] > PRESS_HEIGHT:
            return None
        near = np.linalg.norm(self._buttons - ee[:2], axis=1) < PRESS_RADIUS
        if not near.any():
            return None
        option = int(np.argmax(near))
        if not self.feasible(option):
            return Outcome(OutcomeKind.FAILURE, option)
        self.mocap(f"button_{option}")[2] = 0.002  # pressed in
        return Outcome(OutcomeKind.SUCCESS, option, preferred=self.preferred_feasible_option())

    def plan(self, option: int) -> list[Waypoint]:
        x, y = self._buttons[option]
        return [
            Waypoint((x, y, 0.07, self.press_grip)),
            Waypoint((x, y, self.press_z, self.press_grip), dwell=3),
        ]
