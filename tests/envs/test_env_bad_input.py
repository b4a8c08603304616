"""Bad env settings and actions are refused where they enter, naming the setting: before, a NaN action moved
the lite arm to NaN (and lerobot-eval scored the episode a plain failure) or stopped the Panda's IK with an
SVD error, and a zero budget or image size built an env that failed later or never."""

import gymnasium as gym
import numpy as np
import pytest

from lerobot_ccdp.envs import CCDPEnvConfig


def _make(**settings) -> gym.Env:
    config = CCDPEnvConfig(**settings)
    return gym.make(config.gym_id, **{**config.gym_kwargs, "render_mode": None})


@pytest.mark.parametrize("task", ["DoorOpening-lite-v0", "DoorOpening-v0"])
@pytest.mark.parametrize("action", [[np.nan, 0, 0, 0], [np.inf, 0, 0, 0], [0.0, 0.0]])
def test_a_non_finite_or_misshapen_action_is_refused(task, action):
    env = _make(task=task)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite action of shape"):
        env.step(np.asarray(action, dtype=np.float32))


@pytest.mark.parametrize(
    "settings,named",
    [
        ({"max_failures": 0}, "max_failures"),
        ({"max_failures": -1}, "max_failures"),
        ({"render_width": 0}, "render_width"),
        ({"obs_type": "pixels_agent_pos", "observation_width": 0}, "observation_width"),
    ],
)
def test_an_env_setting_below_its_range_is_refused(settings, named):
    with pytest.raises(ValueError, match=named):
        _make(task="DoorOpening-lite-v0", **settings)


def test_an_episode_length_below_one_is_refused_naming_the_flag():
    with pytest.raises(ValueError, match="--env.episode_length must be >= 1"):
        CCDPEnvConfig(task="DoorOpening-lite-v0", episode_length=0)
