"""LeRobot imports the plugin for every CLI: that import registers `ccdp` but loads no MuJoCo, task or
lerobot-eval (lerobot-record or lerobot-teleoperate on a robot should not pay for, or be patched by,
lerobot-eval)."""

import json
import subprocess
import sys

import gymnasium as gym

from lerobot_ccdp.envs import TASKS, gym_id
from lerobot_ccdp.envs.tasks import ENTRY_POINTS

CHECK = """
import json, sys
import lerobot_policy_ccdp
from lerobot.configs.policies import PreTrainedConfig
from lerobot.envs.configs import EnvConfig

loaded = sorted(
    m for m in sys.modules if m == "mujoco" or m.startswith(("lerobot.scripts", "lerobot_ccdp.envs."))
)
policy, env = PreTrainedConfig.get_choice_class("ccdp"), EnvConfig.get_choice_class("ccdp")

import gymnasium as gym
made = gym.make("lerobot_ccdp/DoorOpening-lite-v0")
made.reset(seed=0)
print(json.dumps({"loaded": loaded, "policy": policy.__name__, "env": env.__name__,
                  "made": type(made.unwrapped).__name__, "mujoco_after_make": "mujoco" in sys.modules}))
"""


def test_plugin_import_registers_ccdp_without_loading_mujoco_tasks_or_lerobot_eval():
    result = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    # Only the light env modules: the config, the task table and the constants LeRobot sees.
    assert report["loaded"] == [
        "lerobot_ccdp.envs.configuration_env",
        "lerobot_ccdp.envs.interface",
        "lerobot_ccdp.envs.tasks",
    ]
    assert (report["policy"], report["env"]) == ("CCDPConfig", "CCDPEnvConfig")
    assert report["made"] == "DoorOpeningEnv" and report["mujoco_after_make"]


def test_registered_step_limits_match_the_task_classes():
    for task in TASKS:
        assert gym.spec(gym_id(task)).max_episode_steps == TASKS[task].default_episode_steps, task
        assert ENTRY_POINTS[task][0] == f"{TASKS[task].__module__}:{TASKS[task].__name__}"
