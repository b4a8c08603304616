"""Shared machinery of the five CCDP tasks: robot control, attempts, failure restore, metrics and rendering.

A task is a sequence of stages (one for door, button and manipulation; one per object or cup for packing and
bartender). In each stage the robot commits to one *option* (door direction, button, pick/push, basket, cup).
A committed option either fails (the hidden parameter rules it out), finishes the stage, or finishes the task.
On a failure the env flags `failure`, puts the robot back to the pose it had when the attempt started (objects
stay where they are unless the task says otherwise) and a new attempt begins from there.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from enum import Enum
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from lerobot_ccdp.envs.camera import CameraRenderer
from lerobot_ccdp.envs.interface import (  # noqa: F401  (re-exported for recorders)
    ACTION_NAMES,
    AGENT_POS_DIM,
    AGENT_POS_NAMES,
    CONTROL_FPS,
    OBS_TYPES,
    OBSERVATION_SIZE,
)
from lerobot_ccdp.envs.scene import CAMERAS, OFFSCREEN_SIZE, WORKSPACE_HIGH, WORKSPACE_LOW, CartesianGripper

# The keys reset's `options` may hold.
RESET_OPTIONS = ("hidden_param",)


class OutcomeKind(Enum):
    FAILURE = "failure"
    STAGE_DONE = "stage_done"
    SUCCESS = "success"


@dataclass(frozen=True)
class Outcome:
    """The end of one attempt: which option was committed to, and (for successes) the option preferred
    then."""

    kind: OutcomeKind
    option: int
    preferred: int | None = None


@dataclass(frozen=True)
class Waypoint:
    """An end-effector target (x, y, z, grip) to reach in a straight line, then hold for `dwell` steps."""

    target: tuple[float, float, float, float]
    dwell: int = 0


class CCDPTaskEnv(gym.Env, abc.ABC):
    """Base class: subclasses describe the task's bodies, hidden parameter, rules, options and expert
    plans."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": CONTROL_FPS}

    name: str
    task_description: str
    n_options: int
    env_state_names: tuple[str, ...]  # one name per environment_state dimension
    default_episode_steps: int
    home: tuple[float, float, float, float]  # robot start pose (x, y, z, grip)
    # The robot and its scene: the lite tasks' Cartesian gripper, or the physics tasks' Franka Panda. It
    # builds the model around the task's bodies, reads the end effector and executes (x, y, z, grip) targets.
    robot_class: type = CartesianGripper

    def __init__(
        self,
        render_mode: str | None = None,
        max_failures: int | None = None,
        init_noise: float = 0.01,
        layout_noise: float = 0.01,
        render_width: int = 320,
        render_height: int = 240,
        obs_type: str = "state",
        cameras: tuple[str, ...] = ("front",),
        observation_width: int = OBSERVATION_SIZE,
        observation_height: int = OBSERVATION_SIZE,
    ):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}"
            )
        if obs_type not in OBS_TYPES:
            raise ValueError(f"obs_type must be one of {list(OBS_TYPES)}, got {obs_type!r}")
        unknown = sorted(set(cameras) - set(CAMERAS))
        if unknown or not cameras or isinstance(cameras, str):
            shown = repr(cameras) if isinstance(cameras, str) else list(cameras)
            raise ValueError(f"cameras must name one or more of {list(CAMERAS)} in a list, got {shown}")
        sizes = {
            "max_failures": 1 if max_failures is None else max_failures,
            "render_width": render_width,
            "render_height": render_height,
            "observation_width": observation_width,
            "observation_height": observation_height,
        }
        noise = {"init_noise": init_noise, "layout_noise": layout_noise}
        # checked as numbers first: a quoted value ('3') would fail the comparisons below with numpy's words
        kinds = [(sizes, int | np.integer), (noise, int | float | np.integer | np.floating)]
        mistyped = {
            name: value
            for values, kind in kinds
            for name, value in values.items()
            if isinstance(value, bool) or not isinstance(value, kind)
        }
        if mistyped:
            raise ValueError(
                f"{mistyped}: the attempt budget and image sizes are whole numbers, the noise levels "
                "numbers. Fix the env setting (--env.<name>, or the recipe's env_kwargs), written without "
                "quotes."
            )
        small = {name: value for name, value in sizes.items() if not value >= 1}
        small |= {name: value for name, value in noise.items() if not (np.isfinite(value) and value >= 0)}
        if small:
            raise ValueError(
                f"{small}: the attempt budget and image sizes must be >= 1, the noise levels finite and "
                ">= 0. Fix the env setting (--env.<name>, or the recipe's env_kwargs)."
            )
        large = {  # MuJoCo refused them at the first frame (a video's: after the first episode's steps)
            name: value
            for name, value in sizes.items()
            if value > OFFSCREEN_SIZE[name.endswith("height")] and not name.startswith("max")
        }
        if large:
            raise ValueError(
                f"{large}: images are rendered at most {OFFSCREEN_SIZE[0]} wide and {OFFSCREEN_SIZE[1]} high "
                "(the scene's offscreen buffer). Fix the env setting (--env.<name>, or the recipe's "
                "env_kwargs)."
            )
        self.render_mode = render_mode
        self.max_failures = self.n_options if max_failures is None else max_failures
        self.init_noise = init_noise
        self.layout_noise = layout_noise
        self.render_width, self.render_height = render_width, render_height
        self.obs_type, self.cameras = obs_type, tuple(cameras)
        self._camera_renderer = (
            CameraRenderer(observation_width, observation_height) if obs_type != "state" else None
        )

        self.model = self.robot_class.build_model(self.name, self._task_bodies_xml())
        self.data = mujoco.MjData(self.model)
        self.robot = self.robot_class(self.model, self.data)
        # LeRobot's eval videos; made without shadows or reflections like the camera observations, which on
        # the Panda scene cuts a 160 x 120 frame from about 107 to 41 ms in software OpenGL.
        self._video_renderer = CameraRenderer(render_width, render_height)
        self._mocap_ids: dict[str, int] = {}

        self.action_space = spaces.Box(
            low=np.array([*WORKSPACE_LOW, 0.0], dtype=np.float32),
            high=np.array([*WORKSPACE_HIGH, 1.0], dtype=np.float32),
            dtype=np.float32,
        )
        observations = {"agent_pos": spaces.Box(-1.0, 1.0, shape=(AGENT_POS_DIM,), dtype=np.float32)}
        if self._camera_renderer is None:
            observations["environment_state"] = spaces.Box(
                -1.0, 1.0, shape=(len(self.env_state_names),), dtype=np.float32
            )
        else:
            frame = spaces.Box(0, 255, shape=(observation_height, observation_width, 3), dtype=np.uint8)
            observations["pixels"] = spaces.Dict(dict.fromkeys(self.cameras, frame))
        observations["failure"] = spaces.Box(0.0, 1.0, shape=(1,), dtype=np.float32)
        self.observation_space = spaces.Dict(observations)
        self.hidden_param = 0
        self.attempt_index = 0
        self._has_reset = False  # step() needs a successful reset first
        self.attempt_start_pose = np.asarray(self.home, dtype=np.float64)

    # ----------------------------------------------------------------------------------------------------
    # What a task provides
    @abc.abstractmethod
    def _task_bodies_xml(self) -> str:
        """MJCF body elements of the task's objects."""

    @abc.abstractmethod
    def hidden_values(self) -> list[int]:
        """Every valid hidden parameter (an integer code; see each task for its meaning)."""

    @abc.abstractmethod
    def _sample_hidden(self) -> int:
        """Draw the episode's hidden parameter from `self.np_random`."""

    @abc.abstractmethod
    def _reset_task(self) -> None:
        """Lay the objects out (drawing layout noise from `self.np_random`) and clear the task's progress."""

    @abc.abstractmethod
    def _update_task(self) -> Outcome | None:
        """Apply the task's rules after a control step; return an outcome when an attempt concludes."""

    @abc.abstractmethod
    def _environment_state(self) -> np.ndarray:
        """Low-dimensional object state; it must not depend on the hidden parameter before an attempt."""

    @abc.abstractmethod
    def preference_order(self) -> list[int]:
        """Options open in the current stage, demonstrator's preference first (uses no hidden information)."""

    @abc.abstractmethod
    def feasible(self, option: int) -> bool:
        """Whether `option` succeeds in the current stage (uses the hidden parameter: for experts only)."""

    @abc.abstractmethod
    def plan(self, option: int) -> list[Waypoint]:
        """Scripted motion that executes `option` for the current stage from the current state."""

    def _apply_hidden(self) -> None:
        """Give the simulation the episode's hidden parameter (a physics task's mass, say); default: nothing,
        the task's rules read `hidden_param` themselves. Called after the layout, before the first
        observation."""

    def _on_failure(self, option: int) -> None:
        """Undo what the failed attempt did to the objects (default: nothing; objects stay put)."""

    # ----------------------------------------------------------------------------------------------------
    # Helpers for tasks
    @property
    def ee_pos(self) -> np.ndarray:
        return self.robot.ee_pos()

    @property
    def grip(self) -> float:
        """Measured gripper closure: 0 open, 1 closed."""
        return self.robot.grip()

    def mocap(self, body: str) -> np.ndarray:
        """Writable view of a mocap body's position."""
        if body not in self._mocap_ids:
            self._mocap_ids[body] = self.model.body(body).mocapid[0]
        return self.data.mocap_pos[self._mocap_ids[body]]

    def free_pose(self, joint: str) -> np.ndarray:
        """Writable view of a free body's pose (position, then quaternion), by its free joint's name."""
        adr = self.model.joint(joint).qposadr[0]
        return self.data.qpos[adr : adr + 7]

    def free_velocity(self, joint: str) -> np.ndarray:
        """Writable view of a free body's velocity (linear, then angular), by its free joint's name."""
        adr = self.model.joint(joint).dofadr[0]
        return self.data.qvel[adr : adr + 6]

    def place_free_body(self, joint: str, position, quaternion=(1.0, 0.0, 0.0, 0.0)) -> None:
        """Put a free body at `position` (upright unless `quaternion` says otherwise), at rest."""
        self.free_pose(joint)[:] = [*position, *quaternion]
        self.free_velocity(joint)[:] = 0.0

    def jitter(self, *shape: int) -> np.ndarray:
        return self.np_random.uniform(-self.layout_noise, self.layout_noise, size=shape)

    def preferred_feasible_option(self) -> int:
        """The demonstrator's choice: the first option in preference order that works."""
        for option in self.preference_order():
            if self.feasible(option):
                return option
        raise RuntimeError(f"{self.name}: no feasible option in stage (hidden_param={self.hidden_param})")

    def _start_pose(self) -> tuple[float, float, float, float]:
        """Where an episode starts, before `init_noise`: `home` (a task may vary it for its
        demonstrations)."""
        return self.home

    def hidden_label(self) -> float:
        return float(self.hidden_param)

    # ----------------------------------------------------------------------------------------------------
    # gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset; `options={"hidden_param": code}` forces the hidden parameter (tests, balanced recording).
        The arguments are checked before anything changes, so a refused reset leaves the env as it was."""
        forced = self._checked_reset_arguments(seed, options)
        self._has_reset = False  # until this reset is through
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        start = np.asarray(self._start_pose(), dtype=np.float64).copy()
        self._start_noise = self.np_random.uniform(-self.init_noise, self.init_noise, size=3)
        start[:3] += self._start_noise
        self.robot.place(start)
        self._reset_task()
        # Drawn last, so the layout (and the first observation) never depends on it (beyond what a task's
        # `_apply_hidden` does with it: only the Bartender's recording options `right_start` and
        # `after_fill_start`).
        self.hidden_param = self._sample_hidden() if forced is None else forced
        self._apply_hidden()
        self._attempts = self._failures = self._repeated_failures = self._attempts_after_failure = 0
        self._failed_options: set[int] = set()
        self._last_option = -1
        self._matched = True
        self._success = False
        self.attempt_index = -1
        self._begin_attempt()
        mujoco.mj_forward(self.model, self.data)
        self._has_reset = True
        return self._observation(failure=False), self._info()

    def _checked_reset_arguments(self, seed: Any, options: Any) -> int | None:
        """The hidden parameter `options` forces (None: drawn), once `seed` and `options` are known good."""
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
            raise ValueError(
                f"{self.name}: reset's seed must be None or an integer >= 0; got {seed!r}. Pass a "
                "non-negative seed, or none for a random episode."
            )
        if options is None:
            return None
        unknown = sorted(map(str, set(options) - set(RESET_OPTIONS))) if isinstance(options, dict) else None
        if unknown is None or unknown:
            raise ValueError(
                f"{self.name}: reset's options take only the keys {list(RESET_OPTIONS)}; got {options!r}."
            )
        forced = options.get("hidden_param")
        if forced is None:
            return None
        values = self.hidden_values()
        if isinstance(forced, bool) or not isinstance(forced, (int, np.integer)) or forced not in values:
            raise ValueError(
                f"{self.name}: hidden_param {forced!r} not in {values}: reset's options['hidden_param'] "
                "forces one of these; leave it out for a drawn one."
            )
        return int(forced)

    def step(self, action):
        if not self._has_reset:
            raise RuntimeError(
                f"{type(self).__name__}.step before a successful reset: call env.reset() first (a refused "
                "reset leaves the env as it was)."
            )
        given = action
        try:
            action = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            action = None  # not numbers: refused below, as given
        if action is None or action.shape != self.action_space.shape or not np.isfinite(action).all():
            shown = repr(given) if action is None else action.tolist()
            raise ValueError(
                f"{type(self).__name__}.step takes a finite action of shape {self.action_space.shape} "
                f"(an end-effector target); got {shown}. A NaN action usually comes from a policy fed NaN "
                "observations or settings."
            )
        action = np.clip(action, self.action_space.low, self.action_space.high)
        self.robot.step(action)

        failure = terminated = False
        outcome = self._update_task()
        if outcome is not None:
            self._attempts += 1
            self._attempts_after_failure += int(self._failures > 0)  # a chance to repeat a failed option
            self._last_option = outcome.option
            if outcome.kind is OutcomeKind.FAILURE:
                failure = True
                self._failures += 1
                self._repeated_failures += int(outcome.option in self._failed_options)
                self._failed_options.add(outcome.option)
                self.robot.restore(self._attempt_start_robot)
                self._on_failure(outcome.option)
                terminated = self._failures >= self.max_failures
            else:
                self._matched &= outcome.option == outcome.preferred
                self._success = outcome.kind is OutcomeKind.SUCCESS
                terminated = self._success
            self._begin_attempt()
        mujoco.mj_forward(self.model, self.data)
        reward = 1.0 if self._success else 0.0
        return self._observation(failure), reward, terminated, False, self._info()

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return self._video_renderer.render(self.model, self.data, self.robot_class.video_camera)

    def close(self):
        self._video_renderer.close()
        if self._camera_renderer is not None:
            self._camera_renderer.close()

    # ----------------------------------------------------------------------------------------------------
    def _begin_attempt(self) -> None:
        self.attempt_index += 1
        self.attempt_start_pose = np.array([*self.ee_pos, self.grip])
        self._attempt_start_robot = self.robot.snapshot()

    def _observation(self, failure: bool) -> dict[str, Any]:
        observation: dict[str, Any] = {"agent_pos": np.array([*self.ee_pos, self.grip], dtype=np.float32)}
        if self._camera_renderer is None:
            observation["environment_state"] = self._environment_state().astype(np.float32)
        else:
            observation["pixels"] = {
                camera: self._camera_renderer.render(self.model, self.data, camera) for camera in self.cameras
            }
        observation["failure"] = np.array([1.0 if failure else 0.0], dtype=np.float32)
        return observation

    def _info(self) -> dict[str, Any]:
        return {
            "is_success": self._success,
            "attempts": self._attempts,
            "failures": self._failures,
            "repeated_failures": self._repeated_failures,
            "attempts_after_failure": self._attempts_after_failure,
            "preference_matched": self._success and self._matched,
            "option": self._last_option,
        }
