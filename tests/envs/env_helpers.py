"""Test helpers for the task envs."""

from __future__ import annotations

import gymnasium as gym

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
