"""The task table: gymnasium ids and the env class of each task, imported only when that task is used.

LeRobot imports the plugin for every CLI (`lerobot-record` on a real robot too), so this table names each
class by its entry-point string: listing tasks, checking a task id or registering the gym ids imports no
MuJoCo, and gymnasium imports a task's module on its first `gym.make`.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from lerobot_ccdp.envs.base import CCDPTaskEnv

GYM_NAMESPACE = "lerobot_ccdp"

# Task id -> (env class as "module:Class", step limit of its gym id). `<Task>-v0` is the task with contact
# physics on the Franka Panda, `<Task>-lite-v0` its geometric version. The step limit repeats the class's
# `default_episode_steps` so registering needs no import; tests/compat/test_plugin_import.py checks that they
# agree.
ENTRY_POINTS: dict[str, tuple[str, int]] = {
    "DoorOpening-v0": ("lerobot_ccdp.envs.door_opening_physics:DoorOpeningPhysicsEnv", 150),
    "ButtonSearch-v0": ("lerobot_ccdp.envs.button_search_physics:ButtonSearchPhysicsEnv", 200),
    "ObjectManipulation-v0": (
        "lerobot_ccdp.envs.object_manipulation_physics:ObjectManipulationPhysicsEnv",
        150,
    ),
    "ObjectPacking-v0": ("lerobot_ccdp.envs.object_packing_physics:ObjectPackingPhysicsEnv", 300),
    "Bartender-v0": ("lerobot_ccdp.envs.bartender_physics:BartenderPhysicsEnv", 250),
    # The same tasks with geometric interaction rules on a free gripper, 20-40x faster per step
    # (docs/tasks.md).
    "DoorOpening-lite-v0": ("lerobot_ccdp.envs.door_opening:DoorOpeningEnv", 150),
    "ButtonSearch-lite-v0": ("lerobot_ccdp.envs.button_search:ButtonSearchEnv", 200),
    "ObjectManipulation-lite-v0": ("lerobot_ccdp.envs.object_manipulation:ObjectManipulationEnv", 150),
    "ObjectPacking-lite-v0": ("lerobot_ccdp.envs.object_packing:ObjectPackingEnv", 300),
    "Bartender-lite-v0": ("lerobot_ccdp.envs.bartender:BartenderEnv", 250),
}


class _TaskTable(Mapping[str, "type[CCDPTaskEnv]"]):
    """Task id -> env class. Iterating and membership tests import nothing; a lookup imports that task."""

    def __getitem__(self, task: str) -> type[CCDPTaskEnv]:
        module, _, name = ENTRY_POINTS[task][0].partition(":")
        return getattr(importlib.import_module(module), name)

    def __contains__(self, task: object) -> bool:
        return task in ENTRY_POINTS

    def __iter__(self) -> Iterator[str]:
        return iter(ENTRY_POINTS)

    def __len__(self) -> int:
        return len(ENTRY_POINTS)


TASKS: Mapping[str, type[CCDPTaskEnv]] = _TaskTable()


def _task_name(task: str) -> str:
    """A task id such as "DoorOpening-v0" (the gym namespace prefix is optional), checked against the
    table."""
    name = task.removeprefix(f"{GYM_NAMESPACE}/")
    if name not in ENTRY_POINTS:
        raise ValueError(f"Unknown ccdp task {task!r}; known tasks: {', '.join(ENTRY_POINTS)}")
    return name


def is_lite(task: str) -> bool:
    """Whether `task` is a geometric version (`<Task>-lite-v0`) rather than the physics task on the Panda."""
    return task.endswith("-lite-v0")


def task_family(task: str) -> str:
    """The task both versions share: "Bartender-v0" and "Bartender-lite-v0" -> "Bartender"."""
    return task.removeprefix(f"{GYM_NAMESPACE}/").split("-")[0]


def task_class(task: str) -> type[CCDPTaskEnv]:
    """Env class of a task id such as "DoorOpening-v0" (imports the task's module, and MuJoCo)."""
    return TASKS[_task_name(task)]


def gym_id(task: str) -> str:
    return f"{GYM_NAMESPACE}/{_task_name(task)}"


def register_tasks() -> None:
    """Register every task with gymnasium by entry-point string (idempotent; imports no task).

    Without gymnasium's passive env checker, as LeRobot makes its envs: that wrapper marks its first reset
    done before calling it, so after a refused first reset (a negative seed) every step failed in the wrapper
    ("cannot unpack non-iterable NoneType object"). The tests run gymnasium's full `check_env` on every task
    instead."""
    import gymnasium as gym

    for task, (entry_point, step_limit) in ENTRY_POINTS.items():
        env_id = f"{GYM_NAMESPACE}/{task}"
        if env_id not in gym.registry:
            gym.register(
                id=env_id, entry_point=entry_point, max_episode_steps=step_limit, disable_env_checker=True
            )
