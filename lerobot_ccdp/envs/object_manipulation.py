"""ObjectManipulation: bring a box to a target; light boxes are picked up, heavy ones slip and must be
pushed."""

from __future__ import annotations

import numpy as np

from lerobot_ccdp.envs.base import CCDPTaskEnv, Outcome, OutcomeKind, Waypoint
from lerobot_ccdp.envs.grasping import Grasp, pick_and_place
from lerobot_ccdp.envs.scene import mocap_box, mocap_cylinder

BOX = np.array([0.0, 0.0, 0.02])
TARGET_XY = np.array([0.0, 0.2])
HALF = 0.02
TARGET_RADIUS = 0.03
PICK, PUSH = 0, 1


class ObjectManipulationEnv(CCDPTaskEnv):
    """Option 0 picks the box up and carries it, option 1 pushes it along the table; pick is preferred.

    hidden_param: 0 light, 1 heavy (equally likely). Lifting a heavy box is a failure (it slips out of the
    gripper); pushing works for both, so on a light box it succeeds without matching the preference.
    """

    name = "ObjectManipulation"
    task_description = "Bring the box to the target."
    n_options = 2
    env_state_names = ("box_x", "box_y", "box_z", "target_x", "target_y")
    default_episode_steps = 150
    home = (0.0, -0.15, 0.12, 0.0)
    push_grip = 0.0  # gripper closure while pushing

    def _task_bodies_xml(self) -> str:
        return "\n".join(
            [
                mocap_cylinder("target", (*TARGET_XY, 0.001), 0.035, 0.001, "0.2 0.7 0.3 1"),
                mocap_box("box", BOX, (HALF, HALF, HALF), "0.2 0.35 0.8 1"),
            ]
        )

    def hidden_values(self) -> list[int]:
        return [0, 1]

    def _sample_hidden(self) -> int:
        return int(self.np_random.integers(2))

    def _reset_task(self) -> None:
        self._target = TARGET_XY + self.jitter(2)
        self.mocap("target")[:2] = self._target
        self.mocap("box")[:] = BOX + np.array([*self.jitter(2), 0.0])
        self._grasp = Grasp(HALF)

    def _environment_state(self) -> np.ndarray:
        return np.concatenate([self.mocap("box"), self._target])

    def preference_order(self) -> list[int]:
        return [PICK, PUSH]

    def feasible(self, option: int) -> bool:
        return option == PUSH or self.hidden_param == 0

    def _at_target(self) -> bool:
        return bool(np.linalg.norm(self.mocap("box")[:2] - self._target) < TARGET_RADIUS)

    def _update_task(self) -> Outcome | None:
        box = self.mocap("box")
        event = self._grasp.update(self.ee_pos, self.grip, box)
        if event == "lifted" and not self.feasible(PICK):
            self._grasp.drop(box)
            return Outcome(OutcomeKind.FAILURE, PICK)
        if event == "released" and self._at_target():
            return Outcome(OutcomeKind.SUCCESS, PICK, preferred=self.preferred_feasible_option())
        if self._grasp.active:
            return None
        ee = self.ee_pos
        behind = box[1] - 2 * HALF < ee[1] < box[1] - HALF / 2
        if ee[2] < 2.5 * HALF and abs(ee[0] - box[0]) < 1.5 * HALF and behind:
            box[1] = ee[1] + 2 * HALF  # pushed along +y
            if self._at_target():
                return Outcome(OutcomeKind.SUCCESS, PUSH, preferred=self.preferred_feasible_option())
        return None

    def box_position(self) -> np.ndarray:
        return self.mocap("box").copy()

    def plan(self, option: int) -> list[Waypoint]:
        bx, by, bz = self.box_position()
        tx, ty = self._target
        if option == PICK:
            return pick_and_place((bx, by, bz), (tx, ty), bz + 0.01)
        start_y = by - 3.5 * HALF
        return [
            Waypoint((bx, start_y, 0.1, self.push_grip)),
            Waypoint((bx, start_y, HALF, self.push_grip)),
            Waypoint((tx, ty - 1.75 * HALF, HALF, self.push_grip), dwell=2),
        ]
