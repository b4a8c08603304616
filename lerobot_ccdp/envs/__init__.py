"""The five CCDP evaluation tasks as gymnasium envs (`lerobot_ccdp/<Task>-v0`) and the LeRobot env type `ccdp`."""

from lerobot_ccdp.envs.base import CCDPTaskEnv, Outcome, OutcomeKind, Waypoint
from lerobot_ccdp.envs.configuration_env import CCDPEnvConfig
from lerobot_ccdp.envs.tasks import GYM_NAMESPACE, TASKS, gym_id, register_tasks, task_class

register_tasks()

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
