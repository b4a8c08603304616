"""The task table: gymnasium ids, env classes and their LeRobot-facing dimensions."""

from __future__ import annotations

from lerobot_ccdp.envs.bartender import BartenderEnv
from lerobot_ccdp.envs.base import CCDPTaskEnv
from lerobot_ccdp.envs.button_search import ButtonSearchEnv
from lerobot_ccdp.envs.door_opening import DoorOpeningEnv
from lerobot_ccdp.envs.object_manipulation import ObjectManipulationEnv
from lerobot_ccdp.envs.object_packing import ObjectPackingEnv

GYM_NAMESPACE = "lerobot_ccdp"

TASKS: dict[str, type[CCDPTaskEnv]] = {
    f"{cls.name}-v0": cls
    for cls in (DoorOpeningEnv, ButtonSearchEnv, ObjectManipulationEnv, ObjectPackingEnv, BartenderEnv)
}


def task_class(task: str) -> type[CCDPTaskEnv]:
    """Env class of a task id such as "DoorOpening-v0" (the gym namespace prefix is optional)."""
    name = task.removeprefix(f"{GYM_NAMESPACE}/")
    if name not in TASKS:
        raise ValueError(f"Unknown ccdp task {task!r}; known tasks: {', '.join(TASKS)}")
    return TASKS[name]


def gym_id(task: str) -> str:
    task_class(task)
    return f"{GYM_NAMESPACE}/{task.removeprefix(f'{GYM_NAMESPACE}/')}"


def register_tasks() -> None:
    """Register every task with gymnasium (idempotent)."""
    import gymnasium as gym

    for task, cls in TASKS.items():
        env_id = f"{GYM_NAMESPACE}/{task}"
        if env_id not in gym.registry:
            gym.register(
                id=env_id,
                entry_point=f"{cls.__module__}:{cls.__name__}",
                max_episode_steps=cls.default_episode_steps,
            )
