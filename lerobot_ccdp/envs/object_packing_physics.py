"""ObjectPacking on the Franka Panda with contact physics: crates that are full inside have no room.

Same options, hidden parameter, preferences, observations and metrics as the lite task (`object_packing.py`).
Each basket is a closed crate with a drop slot in its lid, deep enough for two objects. A crate of capacity c
holds, at its bottom, a block as tall as 2 - c objects (the crate's own colour, out of the front camera's view
under the lid), so the hidden parameter is room that the simulation takes away: an object dropped through the
slot of a crate without room comes to rest on what is inside, sticking out of the slot. The env reads where a
released object comes to rest: under the lid it is packed; on a crate but not under the lid it is a failure
(the object is then handed back to where it started, as in the lite task); elsewhere it has to be picked
again.
"""

from __future__ import annotations

import numpy as np

from lerobot_ccdp.envs.base import Outcome, OutcomeKind
from lerobot_ccdp.envs.object_packing import (
    BASKETS_XY,
    HALF,
    MAX_CAPACITY,
    OBJECTS_XY,
    ObjectPackingEnv,
    decode_capacities,
)
from lerobot_ccdp.envs.panda import PandaArm

WALL = 0.004  # crate wall, floor and lid thickness
INNER = 0.03  # half the crate's inner width
SLOT = 0.026  # half the width of the slot in the lid (an object's half width is 0.018)
DEPTH = MAX_CAPACITY * 2 * HALF + 0.008  # inner height: room for two objects stacked
LID = WALL + DEPTH  # height of the lid's underside
LIFTED = HALF + 0.02  # an object this high has been picked up
RESTED = 0.02  # m/s: a released object slower than this has come to rest
CRATE = "0.6 0.45 0.25 1"
HIDDEN_GROUP = 3  # MuJoCo renders geom groups 0-2 by default


def _box(size, pos, name: str = "", group: int = 0) -> str:
    """One box geom of a crate, in the crate's colour."""
    named = f'name="{name}" ' if name else ""
    return (
        f'<geom {named}type="box" size="{size[0]} {size[1]} {size[2]}" pos="{pos[0]} {pos[1]} {pos[2]}"'
        f' rgba="{CRATE}" group="{group}"/>'
    )


def _crate_xml(i: int) -> str:
    """Crate i: floor, four walls, a lid of four plates around the slot, and the filler at the bottom."""
    x, y = BASKETS_XY[i]
    outer, gap = INNER + WALL, (INNER + WALL - SLOT) / 2
    floor = [_box((outer, outer, WALL / 2), (0, 0, WALL / 2))]
    walls = [
        _box((sx, sy, DEPTH / 2), (px, py, WALL + DEPTH / 2))
        for sx, sy, px, py in [
            (outer, WALL / 2, 0, outer - WALL / 2),
            (outer, WALL / 2, 0, -outer + WALL / 2),
            (WALL / 2, outer, outer - WALL / 2, 0),
            (WALL / 2, outer, -outer + WALL / 2, 0),
        ]
    ]
    lid = [
        _box((sx, sy, WALL / 2), (px, py, LID + WALL / 2))
        for sx, sy, px, py in [
            (outer, gap, 0, SLOT + gap),
            (outer, gap, 0, -SLOT - gap),
            (gap, SLOT, SLOT + gap, 0),
            (gap, SLOT, -SLOT - gap, 0),
        ]
    ]
    # Compiled at its largest (MuJoCo's collision bounds come from the compiled size); sized at reset. In geom
    # group 3, which cameras do not draw: seen through the slot it would show the hidden capacity.
    filler = [
        _box(
            (INNER - 0.001, INNER - 0.001, MAX_CAPACITY * HALF),
            (0, 0, WALL + MAX_CAPACITY * HALF),
            f"filler_{i}",
            group=HIDDEN_GROUP,
        )
    ]
    return f'<body name="basket_{i}" pos="{x} {y} 0">{"".join(floor + walls + lid + filler)}</body>'


class ObjectPackingPhysicsEnv(ObjectPackingEnv):
    """The lite task's basket rule replaced by the simulation (see the module docstring)."""

    robot_class = PandaArm
    # Carried clear of the crates (their lids are 8.8 cm high); released with the object's bottom 2.4 cm above
    # the lid, it drops through the slot.
    place_z, carry_z = 0.13, 0.16

    def _task_bodies_xml(self) -> str:
        crates = [_crate_xml(i) for i in range(len(BASKETS_XY))]
        colours = ["0.85 0.2 0.2 1", "0.2 0.35 0.85 1"]
        objects = [
            f'<body name="object_{i}" pos="{x} {y} {HALF}"><freejoint name="object_{i}"/>'
            f'<geom type="box" size="{HALF} {HALF} {HALF}" mass="0.1" friction="0.8" rgba="{rgba}"/></body>'
            for i, ((x, y), rgba) in enumerate(zip(OBJECTS_XY, colours, strict=True))
        ]
        return "\n".join(crates + objects)

    def object_position(self, i: int) -> np.ndarray:
        return self.free_pose(f"object_{i}")[:3].copy()

    def _reset_task(self) -> None:
        self._baskets = BASKETS_XY + self.jitter(*BASKETS_XY.shape)
        self._objects0 = OBJECTS_XY + self.jitter(*OBJECTS_XY.shape)
        for i, xy in enumerate(self._baskets):
            self.model.body_pos[self.model.body(f"basket_{i}").id][:2] = xy
        for i, xy in enumerate(self._objects0):
            self.place_free_body(f"object_{i}", (*xy, HALF))
        self._counts = [0] * len(BASKETS_XY)
        self._packed = 0
        self._lifted = False

    def _apply_hidden(self) -> None:
        """Fill each crate's bottom with a block as tall as the objects it has no room for."""
        for i, capacity in enumerate(decode_capacities(self.hidden_param)):
            filler = self.model.geom(f"filler_{i}").id
            height = max((MAX_CAPACITY - capacity) * 2 * HALF, 0.001)
            self.model.geom_size[filler][2] = height / 2
            self.model.geom_pos[filler][2] = WALL + height / 2

    def _environment_state(self) -> np.ndarray:
        objects = [self.object_position(i) for i in range(len(OBJECTS_XY))]
        return np.concatenate([*objects, self._baskets.ravel()])

    def _update_task(self) -> Outcome | None:
        i = self._packed
        position = self.object_position(i)
        speed = np.linalg.norm(self.free_velocity(f"object_{i}")[:3])
        if self.grip > 0.4 and position[2] > LIFTED:
            self._lifted = True
        if not self._lifted or self.grip > 0.2 or speed > RESTED:
            return None  # not yet picked, still held, or still falling
        self._lifted = False
        on = np.flatnonzero(np.abs(self._baskets - position[:2]).max(axis=1) < INNER + WALL)
        if on.size == 0:
            return None  # dropped on the table: pick it up again
        basket = int(on[0])
        if position[2] > LID - 0.01:  # resting on what the crate holds, sticking out of the slot: no room
            return Outcome(OutcomeKind.FAILURE, basket)
        preferred = self.preferred_feasible_option()
        self._counts[basket] += 1
        self._packed += 1
        kind = OutcomeKind.SUCCESS if self._packed == len(OBJECTS_XY) else OutcomeKind.STAGE_DONE
        return Outcome(kind, basket, preferred=preferred)

    def _on_failure(self, option: int) -> None:
        """The rejected object is handed back to where it started."""
        self.place_free_body(f"object_{self._packed}", (*self._objects0[self._packed], HALF))
