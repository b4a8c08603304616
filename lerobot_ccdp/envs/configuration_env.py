"""The LeRobot `EnvConfig` of the CCDP tasks: `--env.type=ccdp --env.task=<Task>-v0`."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE

from lerobot_ccdp.compat.env_fit import install_env_fit_check
from lerobot_ccdp.compat.eval_metrics import install_episode_metrics
from lerobot_ccdp.envs.interface import ACTION_DIM, AGENT_POS_DIM, CONTROL_FPS, OBS_TYPES, OBSERVATION_SIZE
from lerobot_ccdp.envs.tasks import gym_id, task_class


@EnvConfig.register_subclass("ccdp")
@dataclass
class CCDPEnvConfig(EnvConfig):
    """A CCDP task. `episode_length` and `max_failures` default to the task's own values.

    `obs_type` works as in gym-pusht: `state` gives `observation.state` and `observation.environment_state`;
    `pixels_agent_pos` gives one `observation.images.<camera>` per camera in `cameras` (rendered at
    `observation_width` x `observation_height`) and `observation.state`. The env's `failure` observation is
    deliberately not a feature here: the policy side passes it through.
    """

    task: str | None = "DoorOpening-v0"
    fps: int = CONTROL_FPS
    episode_length: int | None = None
    max_failures: int | None = None
    render_mode: str | None = "rgb_array"  # null: no rendering (lerobot-eval then saves no videos)
    render_width: int = 320  # size of the frames lerobot-eval's videos show
    render_height: int = 240
    obs_type: str = "state"
    cameras: list[str] = field(default_factory=lambda: ["front"])
    observation_width: int = OBSERVATION_SIZE
    observation_height: int = OBSERVATION_SIZE
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(
        default_factory=lambda: {
            ACTION: ACTION,
            "agent_pos": OBS_STATE,
            "environment_state": OBS_ENV_STATE,
        }
    )

    def __post_init__(self):
        install_episode_metrics()  # an evaluation of ccdp tasks reports their per-episode metrics
        install_env_fit_check()  # and refuses a checkpoint that does not fit the task before it starts
        if self.task is None:
            raise ValueError("--env.task is required for --env.type=ccdp")
        cls = task_class(self.task)
        if self.fps != CONTROL_FPS:
            raise ValueError(f"ccdp tasks run at a fixed {CONTROL_FPS} fps, got --env.fps={self.fps}")
        if self.render_mode not in (None, "rgb_array"):  # gymnasium wrapped "human" in a window
            raise ValueError(
                f"--env.render_mode must be rgb_array (lerobot-eval's videos) or null (none), got "
                f"{self.render_mode!r}"
            )
        if self.obs_type not in OBS_TYPES:
            raise ValueError(f"--env.obs_type must be one of {list(OBS_TYPES)}, got {self.obs_type!r}")
        if self.episode_length is None:
            self.episode_length = cls.default_episode_steps
        if self.episode_length < 1:
            raise ValueError(
                f"--env.episode_length must be >= 1 (steps before an episode is cut off); got "
                f"{self.episode_length}. Leave it out for the task's default, "
                f"{cls.default_episode_steps}."
            )
        self.features = {
            ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(AGENT_POS_DIM,)),
        }
        if self.obs_type == "state":
            self.features["environment_state"] = PolicyFeature(
                type=FeatureType.ENV, shape=(len(cls.env_state_names),)
            )
        else:
            frame = (self.observation_height, self.observation_width, 3)
            for camera in self.cameras:
                self.features[f"pixels/{camera}"] = PolicyFeature(type=FeatureType.VISUAL, shape=frame)
                self.features_map[f"pixels/{camera}"] = f"{OBS_IMAGES}.{camera}"

    @property
    def package_name(self) -> str:
        return "lerobot_ccdp.envs"

    @property
    def gym_id(self) -> str:
        return gym_id(self.task)

    @property
    def gym_kwargs(self) -> dict:
        kwargs = {
            "render_mode": self.render_mode,
            "max_episode_steps": self.episode_length,
            "obs_type": self.obs_type,
        }
        if self.render_mode is not None:
            kwargs.update(render_width=self.render_width, render_height=self.render_height)
        if self.obs_type != "state":
            kwargs.update(
                cameras=tuple(self.cameras),
                observation_width=self.observation_width,
                observation_height=self.observation_height,
            )
        if self.max_failures is not None:
            kwargs["max_failures"] = self.max_failures
        return kwargs
