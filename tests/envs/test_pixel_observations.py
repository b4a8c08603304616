"""obs_type `pixels_agent_pos` (as gym-pusht's): rendered cameras plus the robot state, through gymnasium and
LeRobot."""

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from lerobot.envs.factory import make_env
from lerobot.envs.utils import env_to_policy_features, preprocess_observation
from lerobot.utils.constants import OBS_STATE

from lerobot_ccdp.envs import TASKS, CCDPEnvConfig
from lerobot_ccdp.envs.scripted import Expert, run_episode

from env_helpers import make

PIXELS = {"obs_type": "pixels_agent_pos", "observation_width": 48, "observation_height": 40}


@pytest.mark.parametrize("task", list(TASKS))
def test_gymnasium_env_checker_with_cameras(task):
    env = make(task, disable_env_checker=True, cameras=("front", "top"), **PIXELS)
    check_env(env.unwrapped)
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"agent_pos", "pixels", "failure"}
    assert set(obs["pixels"]) == {"front", "top"}
    for image in obs["pixels"].values():
        assert image.shape == (40, 48, 3) and image.dtype == np.uint8 and image.std() > 0
    env.close()


def test_cameras_see_the_robot_move_and_seeds_repeat():
    env = make("ButtonSearch-lite-v0", **PIXELS)
    first = run_episode(env, Expert(env), seed=4)
    second = run_episode(env, Expert(env), seed=4)
    frames = [o["pixels"]["front"] for o in first.observations]
    assert not np.array_equal(frames[0], frames[len(frames) // 2]), "the image follows the robot"
    for a, b in zip(first.observations, second.observations, strict=True):
        np.testing.assert_array_equal(a["pixels"]["front"], b["pixels"]["front"])


@pytest.mark.parametrize("task", list(TASKS))
def test_images_at_reset_do_not_show_the_hidden_parameter(task):
    env = make(task, cameras=("front", "top"), **PIXELS)
    values = env.unwrapped.hidden_values()
    reference = env.reset(seed=3, options={"hidden_param": values[0]})[0]["pixels"]
    for value in values[1:]:
        images = env.reset(seed=3, options={"hidden_param": value})[0]["pixels"]
        for camera in ("front", "top"):
            np.testing.assert_array_equal(
                images[camera], reference[camera], err_msg=f"{camera}, hidden {value}"
            )
    env.close()


def test_env_config_maps_cameras_to_observation_images():
    config = CCDPEnvConfig(
        task="DoorOpening-lite-v0",
        obs_type="pixels_agent_pos",
        cameras=["front", "top"],
        observation_width=48,
        observation_height=40,
        render_mode=None,
    )
    features = env_to_policy_features(config)
    assert {k: tuple(f.shape) for k, f in features.items() if k.startswith("observation")} == {
        "observation.images.front": (3, 40, 48),
        "observation.images.top": (3, 40, 48),
        OBS_STATE: (4,),
    }
    envs = make_env(config, n_envs=2)
    env = next(iter(next(iter(envs.values())).values()))
    observation = preprocess_observation(env.reset(seed=[0, 1])[0])
    env.close()
    assert observation["observation.images.front"].shape == (2, 3, 40, 48)
    assert observation["observation.failure"].shape == (2, 1)
    assert "observation.environment_state" not in observation


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"obs_type": "pixels"}, "obs_type must be one of"),
        (
            {"obs_type": "pixels_agent_pos", "cameras": ("wrist",)},
            r"cameras must name one or more of \['front', 'top'\]",
        ),
    ],
)
def test_bad_observation_settings_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        make("DoorOpening-lite-v0", **kwargs)
    if "cameras" not in kwargs:
        with pytest.raises(ValueError, match="--env.obs_type"):
            CCDPEnvConfig(task="DoorOpening-lite-v0", **kwargs)
