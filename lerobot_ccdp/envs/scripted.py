"""Scripted agents: the expert that records demonstrations and the no-repeat oracle used as a reference.

Both execute an option with the task's own `plan` (straight-line waypoints at a fixed speed), so demos are
smooth and, given the option, deterministic: the only multimodality left in the data is the option choice.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from lerobot_ccdp.envs.base import CCDPTaskEnv, Waypoint

SPEED = 0.025  # metres per control step (0.25 m/s at 10 fps)


class WaypointFollower:
    """Turns waypoints into end-effector targets that move at most `speed` per step."""

    def __init__(self, waypoints: list[Waypoint], start: np.ndarray, speed: float = SPEED):
        self._waypoints = list(waypoints)
        self._cmd = np.asarray(start, dtype=np.float64).copy()
        self._speed = speed
        self._dwell_left: int | None = None

    def next_action(self) -> np.ndarray:
        if not self._waypoints:
            return self._cmd.copy()
        waypoint = self._waypoints[0]
        target = np.asarray(waypoint.target, dtype=np.float64)
        self._cmd[3] = target[3]
        delta = target[:3] - self._cmd[:3]
        distance = float(np.linalg.norm(delta))
        if distance > self._speed:
            self._cmd[:3] += delta / distance * self._speed
            return self._cmd.copy()
        self._cmd[:3] = target[:3]
        if self._dwell_left is None:
            self._dwell_left = waypoint.dwell
        if self._dwell_left == 0:
            self._waypoints.pop(0)
            self._dwell_left = None
        else:
            self._dwell_left -= 1
        return self._cmd.copy()


class ScriptedAgent(abc.ABC):
    """Chooses an option at the start of every attempt and follows the task's plan for it."""

    def __init__(self, env: gym.Env, speed: float = SPEED):
        self.env: CCDPTaskEnv = env.unwrapped
        self.speed = speed
        self.reset()

    def reset(self) -> None:
        self.option = -1
        self.failed_options: set[int] = set()
        self._attempt: int | None = None
        self._follower: WaypointFollower | None = None

    @abc.abstractmethod
    def choose_option(self) -> int:
        """Option to try in the attempt that starts now."""

    def act(self, observation: dict[str, np.ndarray], info: dict[str, Any]) -> np.ndarray:
        if observation["failure"][0] > 0:
            self.failed_options.add(int(info["option"]))
        if self.env.attempt_index != self._attempt:
            self._attempt = self.env.attempt_index
            self.option = self.choose_option()
            self._follower = WaypointFollower(
                self.env.plan(self.option), observation["agent_pos"], self.speed
            )
        return self._follower.next_action().astype(np.float32)


class Expert(ScriptedAgent):
    """Knows the hidden parameter: always takes the demonstrator's preferred option that works."""

    def choose_option(self) -> int:
        return self.env.preferred_feasible_option()


class NoRepeatOracle(ScriptedAgent):
    """Knows no hidden parameter: tries options in preference order and never repeats a failed one."""

    def choose_option(self) -> int:
        order = self.env.preference_order()
        untried = [o for o in order if o not in self.failed_options]
        return untried[0] if untried else order[0]


@dataclass
class Episode:
    """One rollout: observations before each action, the actions, the agent's option per step, final info."""

    observations: list[dict[str, np.ndarray]] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    options: list[int] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)
    hidden_param: int = 0

    @property
    def success(self) -> bool:
        return bool(self.info.get("is_success", False))


def run_episode(
    env: gym.Env,
    agent: ScriptedAgent,
    seed: int | None = None,
    hidden_param: int | None = None,
    on_step: Callable[[gym.Env], None] | None = None,
) -> Episode:
    """Roll `agent` out in `env` until termination or truncation."""
    options = None if hidden_param is None else {"hidden_param": hidden_param}
    observation, info = env.reset(seed=seed, options=options)
    agent.reset()
    episode = Episode(hidden_param=env.unwrapped.hidden_param)
    done = False
    while not done:
        action = agent.act(observation, info)
        episode.observations.append(observation)
        episode.actions.append(action)
        episode.options.append(agent.option)
        observation, _, terminated, truncated, info = env.step(action)
        if on_step is not None:
            on_step(env)
        done = terminated or truncated
    episode.info = info
    return episode
