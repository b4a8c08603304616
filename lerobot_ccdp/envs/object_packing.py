"""ObjectPacking: put two objects into baskets; the nearest basket is preferred; capacities are hidden."""

from __future__ import annotations

import itertools

import numpy as np

from lerobot_ccdp.envs.base import CCDPTaskEnv, Outcome, OutcomeKind, Waypoint
from lerobot_ccdp.envs.grasping import Grasp, pick_and_place
from lerobot_ccdp.envs.scene import mocap_box

OBJECTS_XY = np.array([[-0.05, -0.08], [0.05, -0.08]])
BASKETS_XY = np.array([[0.0, 0.1], [-0.22, 0.12], [0.26, 0.24]])
HALF = 0.018
BASKET_RADIUS = 0.05  # release the object within this distance of a basket's centre to drop it in
MAX_CAPACITY = 2


def decode_capacities(code: int) -> list[int]:
    """hidden_param -> per-basket capacity (base-3 digits, basket 0 least significant)."""
    return [(code // (MAX_CAPACITY + 1) ** i) % (MAX_CAPACITY + 1) for i in range(len(BASKETS_XY))]


def encode_capacities(capacities: list[int]) -> int:
    return sum(c * (MAX_CAPACITY + 1) ** i for i, c in enumerate(capacities))


def _basket_xml(i: int) -> str:
    x, y = BASKETS_XY[i]
    walls = "".join(
        f'<geom type="box" size="{sx} {sy} 0.02" pos="{px} {py} 0.02" rgba="0.6 0.45 0.25 1"/>'
        for sx, sy, px, py in [
            (0.055, 0.004, 0, 0.055),
            (0.055, 0.004, 0, -0.055),
            (0.004, 0.055, 0.055, 0),
            (0.004, 0.055, -0.055, 0),
        ]
    )
    floor = '<geom type="box" size="0.055 0.055 0.001" rgba="0.7 0.55 0.35 1"/>'
    return f'<body name="basket_{i}" mocap="true" pos="{x} {y} 0">{floor}{walls}</body>'


class ObjectPackingEnv(CCDPTaskEnv):
    """Pick each object in turn and release it over a basket; option i is basket i.

    hidden_param: basket capacities in {0, 1, 2}, base-3 coded (see `decode_capacities`), uniform over the
    codes whose total capacity fits both objects. The demonstrator uses the basket nearest to the object
    that still has room. Releasing over a full basket is a failure: the object is rejected and goes back to
    where it started.
    """

    name = "ObjectPacking"
    task_description = "Pack both objects into baskets."
    n_options = len(BASKETS_XY)
    env_state_names = tuple(f"object{i}_{c}" for i in range(len(OBJECTS_XY)) for c in "xyz") + tuple(
        f"basket{i}_{c}" for i in range(len(BASKETS_XY)) for c in "xy"
    )
    default_episode_steps = 300
    home = (0.0, -0.2, 0.12, 0.0)
    place_z, carry_z = 0.07, 0.1  # end-effector heights: release over a basket, carry

    def _task_bodies_xml(self) -> str:
        baskets = [_basket_xml(i) for i in range(len(BASKETS_XY))]
        objects = [
            mocap_box(f"object_{i}", (x, y, HALF), (HALF, HALF, HALF), rgba)
            for i, ((x, y), rgba) in enumerate(
                zip(OBJECTS_XY, ["0.85 0.2 0.2 1", "0.2 0.35 0.85 1"], strict=True)
            )
        ]
        return "\n".join(baskets + objects)

    def hidden_values(self) -> list[int]:
        combos = itertools.product(range(MAX_CAPACITY + 1), repeat=len(BASKETS_XY))
        return sorted(encode_capacities(list(c)) for c in combos if sum(c) >= len(OBJECTS_XY))

    def _sample_hidden(self) -> int:
        return int(self.np_random.choice(self.hidden_values()))

    def _reset_task(self) -> None:
        self._baskets = BASKETS_XY + self.jitter(*BASKETS_XY.shape)
        self._objects0 = OBJECTS_XY + self.jitter(*OBJECTS_XY.shape)
        for i, xy in enumerate(self._baskets):
            self.mocap(f"basket_{i}")[:2] = xy
        for i, xy in enumerate(self._objects0):
            self.mocap(f"object_{i}")[:] = (*xy, HALF)
        self._counts = [0] * len(BASKETS_XY)
        self._packed = 0
        self._grasp = Grasp(HALF)

    def _environment_state(self) -> np.ndarray:
        objects = [self.mocap(f"object_{i}") for i in range(len(OBJECTS_XY))]
        return np.concatenate([*objects, self._baskets.ravel()])

    def preference_order(self) -> list[int]:
        distances = np.linalg.norm(self._baskets - self._objects0[self._packed], axis=1)
        return [int(i) for i in np.argsort(distances, kind="stable")]

    def feasible(self, option: int) -> bool:
        return self._counts[option] < decode_capacities(self.hidden_param)[option]

    def _update_task(self) -> Outcome | None:
        obj = self.mocap(f"object_{self._packed}")
        if self._grasp.update(self.ee_pos, self.grip, obj) != "released":
            return None
        over = np.linalg.norm(self._baskets - obj[:2], axis=1) < BASKET_RADIUS
        if not over.any():
            return None  # dropped on the table: pick it up again
        basket = int(np.argmax(over))
        if not self.feasible(basket):
            return Outcome(OutcomeKind.FAILURE, basket)
        preferred = self.preferred_feasible_option()
        slot = self._counts[basket]
        obj[:] = (*self._baskets[basket] + np.array([0.04 * slot - 0.02, 0.0]), HALF + 0.002)
        self._counts[basket] += 1
        self._packed += 1
        kind = OutcomeKind.SUCCESS if self._packed == len(OBJECTS_XY) else OutcomeKind.STAGE_DONE
        return Outcome(kind, basket, preferred=preferred)

    def _on_failure(self, option: int) -> None:
        self.mocap(f"object_{self._packed}")[:] = (*self._objects0[self._packed], HALF)

    def plan(self, option: int) -> list[Waypoint]:
        return pick_and_place(
            tuple(self.object_position(self._packed)),
            tuple(self._baskets[option]),
            self.place_z,
            self.carry_z,
        )

    def object_position(self, i: int) -> np.ndarray:
        return self.mocap(f"object_{i}").copy()
