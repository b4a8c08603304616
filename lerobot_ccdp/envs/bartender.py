"""Bartender: fill two cups one after the other; the nearest available cup is preferred; availability is
hidden."""

from __future__ import annotations

import numpy as np

from lerobot_ccdp.envs.base import CCDPTaskEnv, Outcome, OutcomeKind, Waypoint
from lerobot_ccdp.envs.scene import mocap_cylinder

CUPS_XY = np.array([[-0.22, 0.1], [-0.1, 0.1], [0.07, 0.1], [0.29, 0.1]])
N_FILLS = 2
POUR_RADIUS = 0.03
POUR_HEIGHT = 0.1  # hold the bottle below this height over a cup ...
POUR_STEPS = 3  # ... for this many steps to pour
P_AVAILABLE = 0.65
EMPTY_Z, FULL_Z = -0.05, 0.018
RIGHT_CUP = 3  # the cup nearest `right_home`


class BartenderEnv(CCDPTaskEnv):
    """Hold the bottle over a cup to pour; option i is cup i. Pouring into an unavailable cup is a failure.

    hidden_param: bitmask of available cups (bit i for cup i; each available with probability 0.65, at least
    two available). The demonstrator fills the nearest available empty cup from where it stands, twice.

    right_start: probability that an episode whose cup 3 is available starts on the right of the cups
    (`right_home`) instead of `home`. From `home` the nearest cup is cup 0 and cup 3 is never filled first, so
    demonstrations recorded only from there never show cup 3 full; a policy that fills it first then sees an
    input it never saw. From the right the expert then fills cup 3 first, so no demonstration crosses the cups
    with every cup empty in the other direction (with those, a base learnt to stop between two cups). Recipes
    set it for recording, where the start then tells cup 3's availability; evaluation keeps 0 (and then draws
    nothing more from the episode's seed).

    after_fill_start: probability that an episode starts after its first fill: one available cup, drawn
    uniformly, already full and the bottle held over it at the pour height, as after the expert's pour (the
    episode then needs one fill more). From `home` the expert's first fill is the nearest available cup, so
    the demonstrations reach cup k full only where every cup nearer home is unavailable, and each then shows
    one way on (after cup 2 always cup 3); a policy that fills cup 2 first with cup 1 available saw nothing
    else there and pours into cup 3 again after it failed (docs/benchmarks.md). A recording option like
    `right_start` (it overrides it), 0 for evaluation.
    """

    name = "Bartender"
    task_description = "Fill two available cups."
    n_options = len(CUPS_XY)
    env_state_names = tuple(f"cup{i}_{c}" for i in range(len(CUPS_XY)) for c in "xy") + tuple(
        f"cup{i}_filled" for i in range(len(CUPS_XY))
    )
    default_episode_steps = 250
    home = (-0.32, -0.05, 0.15, 1.0)  # the gripper holds the bottle
    # 0.08 right of cup 3 (`home` is 0.10 left of cup 0; 0.39 would put the start noise at the workspace's
    # 0.4 edge)
    right_home = (0.37, -0.05, 0.15, 1.0)
    pour_z = 0.07  # end-effector height while pouring (below POUR_HEIGHT)

    def __init__(self, *args, right_start: float = 0.0, after_fill_start: float = 0.0, **kwargs):
        for name, value in (("right_start", right_start), ("after_fill_start", after_fill_start)):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} is a probability in [0, 1], got {value}")
        super().__init__(*args, **kwargs)
        self.right_start = right_start
        self.after_fill_start = after_fill_start
        self._drew_right = False

    def _start_pose(self) -> tuple[float, float, float, float]:
        self._drew_right = self.right_start > 0.0 and self.np_random.random() < self.right_start
        return self.right_home if self._drew_right else self.home

    def _apply_hidden(self) -> None:
        """A right start drawn for an episode whose cup 3 is unavailable moves to `home` (same start
        noise); an after-fill start (drawn only when `after_fill_start` > 0) fills an available cup and holds
        the bottle over it."""
        if self._drew_right and not self.hidden_param >> RIGHT_CUP & 1:
            start = np.asarray(self.home, dtype=np.float64).copy()
            start[:3] += self._start_noise
            self.robot.place(start)
            self._grasp_bottle()
        if self.after_fill_start > 0.0 and self.np_random.random() < self.after_fill_start:
            cup = int(self.np_random.choice([i for i in range(len(CUPS_XY)) if self.hidden_param >> i & 1]))
            # the episode's start noise, as where a pour ends varies
            self.robot.place(np.array([*self._cups[cup] + self._start_noise[:2], self.pour_z, 1.0]))
            self._grasp_bottle()
            self._filled[cup] = True
            self._show_drinks()
            self._pouring_into, self._pour_steps = cup, -1  # this pour is over: leave the cup to pour again

    def _task_bodies_xml(self) -> str:
        glass, drink = "0.8 0.85 0.9 0.5", "0.9 0.6 0.1 1"
        cups = [
            mocap_cylinder(f"cup_{i}", (x, y, 0.02), 0.025, 0.02, glass) for i, (x, y) in enumerate(CUPS_XY)
        ]
        drinks = [
            mocap_cylinder(f"drink_{i}", (x, y, EMPTY_Z), 0.02, 0.016, drink)
            for i, (x, y) in enumerate(CUPS_XY)
        ]
        bottle = (
            '<body name="bottle" mocap="true">'
            '<geom type="cylinder" size="0.015 0.03" pos="0 0 -0.03" rgba="0.2 0.5 0.25 1"/></body>'
        )
        return "\n".join(cups + drinks + [bottle])

    def hidden_values(self) -> list[int]:
        return [m for m in range(2 ** len(CUPS_XY)) if bin(m).count("1") >= N_FILLS]

    def _sample_hidden(self) -> int:
        while True:
            available = self.np_random.random(len(CUPS_XY)) < P_AVAILABLE
            code = int(sum(1 << i for i, a in enumerate(available) if a))
            if code in self.hidden_values():
                return code

    def _reset_task(self) -> None:
        self._cups = CUPS_XY + self.jitter(*CUPS_XY.shape)
        for i, xy in enumerate(self._cups):
            self.mocap(f"cup_{i}")[:2] = xy
        self._filled = np.zeros(len(CUPS_XY), dtype=bool)
        self._pouring_into, self._pour_steps = -1, 0
        self._show_drinks()
        self._grasp_bottle()

    def _grasp_bottle(self) -> None:
        """The bottle (a mocap body here) goes where the gripper is."""
        self._follow_bottle()

    def _show_drinks(self) -> None:
        """A filled cup shows its drink."""
        for i, filled in enumerate(self._filled):
            self.mocap(f"drink_{i}")[:] = (*self._cups[i], FULL_Z if filled else EMPTY_Z)

    def _follow_bottle(self) -> None:
        self.mocap("bottle")[:] = self.ee_pos

    def _environment_state(self) -> np.ndarray:
        return np.concatenate([self._cups.ravel(), self._filled.astype(np.float64)])

    def preference_order(self) -> list[int]:
        distances = np.linalg.norm(self._cups - self.attempt_start_pose[:2], axis=1)
        return [int(i) for i in np.argsort(distances, kind="stable") if not self._filled[i]]

    def feasible(self, option: int) -> bool:
        return bool(self.hidden_param >> option & 1) and not self._filled[option]

    def _update_task(self) -> Outcome | None:
        self._follow_bottle()
        ee = self.ee_pos
        near = np.linalg.norm(self._cups - ee[:2], axis=1) < POUR_RADIUS
        cup = int(np.argmax(near)) if near.any() and ee[2] < POUR_HEIGHT else -1
        if cup != self._pouring_into:
            # A new pour starts only after the bottle has left the cup it poured into (cup == -1 re-arms).
            self._pouring_into, self._pour_steps = cup, 0
        if cup < 0 or self._pour_steps < 0:
            return None
        self._pour_steps += 1
        if self._pour_steps < POUR_STEPS:
            return None
        self._pour_steps = -1  # this pour is over
        if not self.feasible(cup):
            return Outcome(OutcomeKind.FAILURE, cup)
        preferred = self.preferred_feasible_option()
        self._filled[cup] = True
        self._show_drinks()
        kind = OutcomeKind.SUCCESS if self._filled.sum() == N_FILLS else OutcomeKind.STAGE_DONE
        return Outcome(kind, cup, preferred=preferred)

    def _begin_attempt(self) -> None:
        super()._begin_attempt()
        # After a fill the attempt starts with the bottle still over that cup, its pour over.
        self._pour_at_start = (self._pouring_into, self._pour_steps)

    def _on_failure(self, option: int) -> None:
        """Back at the attempt's start, the pour state too: a bottle restored over the cup it just filled must
        leave that cup before it can pour again, as it had to before the failed attempt."""
        self._pouring_into, self._pour_steps = self._pour_at_start
        self._follow_bottle()

    def plan(self, option: int) -> list[Waypoint]:
        ex, ey, _ = self.ee_pos
        cx, cy = self._cups[option]
        return [
            Waypoint((ex, ey, 0.15, 1.0)),
            Waypoint((cx, cy, 0.15, 1.0)),
            Waypoint((cx, cy, self.pour_z, 1.0), dwell=POUR_STEPS + 1),
        ]
