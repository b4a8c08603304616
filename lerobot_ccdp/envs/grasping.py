"""Rule-based grasping of a box-shaped mocap object (the scene has no contacts, see `scene.py`)."""

from __future__ import annotations

import numpy as np

from lerobot_ccdp.envs.base import Waypoint

CLOSED, OPEN = 0.6, 0.4  # gripper closure thresholds with hysteresis
LIFT = 0.03  # how far the grasped object must be raised before it counts as lifted


class Grasp:
    """Close the gripper around an object to grasp it; raise it `LIFT` to carry it; open to let go.

    `update` returns "lifted" on the step the object leaves the table and "released" on the step a carried
    object is let go (it then rests on the table below the gripper); the task decides what those mean.
    """

    def __init__(self, half_size: float):
        self.half_size = half_size
        self.active = False  # gripper closed around the object
        self.held = False  # object lifted and carried
        self._offset = np.zeros(3)
        self._grasp_z = 0.0

    def update(self, ee: np.ndarray, grip: float, obj: np.ndarray) -> str | None:
        """Advance the grasp; `obj` is the object's writable position."""
        if not self.active:
            near = np.linalg.norm(ee[:2] - obj[:2]) < self.half_size and abs(ee[2] - obj[2]) < self.half_size
            if grip > CLOSED and near:
                self.active, self._offset, self._grasp_z = True, obj - ee, ee[2]
            return None
        if grip < OPEN:
            was_held = self.held
            self.drop(obj)
            return "released" if was_held else None
        event = None
        if not self.held and ee[2] > self._grasp_z + LIFT:
            self.held, event = True, "lifted"
        if self.held:
            obj[:] = ee + self._offset
        return event

    def drop(self, obj: np.ndarray) -> None:
        """Let go: the object falls back onto the table where it is."""
        self.active = self.held = False
        obj[2] = self.half_size


def pick_and_place(
    obj: tuple[float, float, float], dest: tuple[float, float], place_z: float, carry_z: float = 0.1
) -> list[Waypoint]:
    """Expert waypoints that grasp the object at `obj`, carry it at `carry_z` and release it at (dest,
    place_z)."""
    ox, oy, oz = obj
    dx, dy = dest
    return [
        Waypoint((ox, oy, 0.08, 0.0)),
        Waypoint((ox, oy, oz, 0.0), dwell=2),
        Waypoint((ox, oy, oz, 1.0), dwell=3),
        Waypoint((ox, oy, carry_z, 1.0)),
        Waypoint((dx, dy, carry_z, 1.0)),
        Waypoint((dx, dy, place_z, 1.0), dwell=1),
        Waypoint((dx, dy, place_z, 0.0), dwell=3),
    ]
