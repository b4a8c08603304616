"""The five CCDP evaluation tasks as gymnasium envs and the LeRobot env type `ccdp`: `lerobot_ccdp/<Task>-v0`
with contact physics on the Franka Panda, `lerobot_ccdp/<Task>-lite-v0` their geometric versions.

Importing this package registers both without importing MuJoCo or any task; the env machinery
(`CCDPTaskEnv`, `Outcome`, `OutcomeKind`, `Waypoint`) loads on first access.
"""

from typing import Any

from lerobot_ccdp.envs.configuration_env import CCDPEnvConfig
from lerobot_ccdp.envs.tasks import GYM_NAMESPACE, TASKS, gym_id, register_tasks, task_class

register_tasks()

_FROM_BASE = ("CCDPTaskEnv", "Outcome", "OutcomeKind", "Waypoint")


def __getattr__(name: str) -> Any:
    if name in _FROM_BASE:
        from lerobot_ccdp.envs import base

        return getattr(base, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "GYM_NAMESPACE",
    "TASKS",
    "CCDPEnvConfig",
    "CCDPTaskEnv",
    "Outcome",
    "OutcomeKind",
    "Waypoint",
    "gym_id",
    "register_tasks",
    "task_class",
]
