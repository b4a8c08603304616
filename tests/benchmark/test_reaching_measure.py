"""The 2-D family's measurement splits the failed share into clean repeats of a failed goal's path and plans
between that path and another (`reaching_preferences.failed_on_path_share`)."""

import numpy as np

from lerobot_ccdp.benchmark.reaching2d import REACH_STEPS, ReachingTask
from lerobot_ccdp.benchmark.reaching_preferences import failed_on_path_share, on_path_tolerance

HORIZON = 16


def paths(task: ReachingTask, goals: list[int]) -> np.ndarray:
    """Each listed goal's demonstrated path from the origin over a chunk (len(goals), HORIZON, 2)."""
    progress = np.minimum(np.arange(1, HORIZON + 1) / REACH_STEPS, 1.0)
    return np.stack([task.path(g, np.zeros(2), progress) for g in goals])


def test_a_plan_on_the_failed_path_is_a_repeat_and_one_between_two_paths_is_not():
    task = ReachingTask.family_member(100)
    rng = np.random.default_rng(0)
    goals = [int(g) for g in rng.integers(0, len(task.goals), 400)]
    dp_plans = paths(task, goals) + rng.normal(0, 0.02, (len(goals), HORIZON, 2))
    tolerance = on_path_tolerance(task, dp_plans)

    on_failed, neighbour = paths(task, [0, 1])
    between = on_failed + 0.45 * (neighbour - on_failed)  # nearer goal 0's path, but far from it
    assert task.option_of(between[None])[0] == 0
    plans = np.stack([on_failed, between, neighbour, neighbour])

    assert failed_on_path_share(task, plans, [0], tolerance) == 0.25  # only the first: 1 of 4 plans
    assert failed_on_path_share(task, plans, [1], tolerance) == 0.5
    assert failed_on_path_share(task, plans, [2], tolerance) == 0.0
