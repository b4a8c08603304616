"""Test helpers for the task envs."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import pytest

from lerobot_ccdp.envs import gym_id
from lerobot_ccdp.envs.scripted import ScriptedAgent


def make(task: str, **kwargs) -> gym.Env:
    return gym.make(gym_id(task), **kwargs)


class FixedOptions(ScriptedAgent):
    """Tries the given options in turn (one per attempt), repeating the last one once they run out."""

    def __init__(self, env: gym.Env, options: list[int]):
        self.options = options
        super().__init__(env)

    def reset(self) -> None:
        super().reset()
        self._tries = 0

    def choose_option(self) -> int:
        option = self.options[min(self._tries, len(self.options) - 1)]
        self._tries += 1
        return option


def run_cli(*args: str) -> subprocess.CompletedProcess:
    """Run a console script of this venv offline, failing the test with its output if it fails."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    result = subprocess.run(
        [str(Path(sys.executable).parent / args[0]), *args[1:]], capture_output=True, text=True, env=env
    )
    if result.returncode != 0:
        pytest.fail(
            f"{' '.join(args)} failed ({result.returncode}):\n"
            f"{result.stdout[-3000:]}\n{result.stderr[-6000:]}"
        )
    return result
