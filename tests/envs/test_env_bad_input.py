"""Bad env settings and actions are refused where they enter, naming the setting: before, a NaN action moved
the lite arm to NaN (and lerobot-eval scored the episode a plain failure) or stopped the Panda's IK with an
SVD error, and a zero budget or image size built an env that failed later or never."""

import re

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


def _steps(env: gym.Env, n: int = 3) -> list[np.ndarray]:
    """Agent positions after `n` steps towards a fixed target (the same for every env)."""
    target = np.array([0.1, 0.0, 0.2, 0.5], dtype=np.float32)
    return [env.step(target)[0]["agent_pos"] for _ in range(n)]


@pytest.mark.parametrize("seed", [-1, 1.5, "0", True])
def test_a_refused_seed_leaves_the_env_ready_for_the_next_reset(seed):
    """Through gym.make, the route a Python user takes: before, gymnasium's passive env checker broke every
    step after a refused first reset ("cannot unpack non-iterable NoneType object")."""
    env = gym.make("lerobot_ccdp/DoorOpening-lite-v0")
    with pytest.raises(ValueError, match=r"seed must be None or an integer >= 0; got"):
        env.reset(seed=seed)
    with pytest.raises(RuntimeError, match=r"step before a successful reset: call env.reset\(\) first"):
        env.step(env.action_space.sample())
    first = env.reset(seed=0)[0]["agent_pos"]
    twin = gym.make("lerobot_ccdp/DoorOpening-lite-v0")
    np.testing.assert_array_equal(first, twin.reset(seed=0)[0]["agent_pos"])
    np.testing.assert_array_equal(_steps(env), _steps(twin))


@pytest.mark.parametrize(
    "options,named",
    [
        ({"hidden_param": 99}, r"hidden_param 99 not in \[0, 1\]"),
        ({"hidden_param": 0.5}, r"hidden_param 0.5 not in \[0, 1\]"),
        ({"hidden_parm": 1}, r"options take only the keys \['hidden_param'\]; got \{'hidden_parm': 1\}"),
        ("hidden_param=1", r"options take only the keys \['hidden_param'\]"),
    ],
)
def test_a_refused_reset_mid_episode_leaves_the_episode_as_it_was(options, named):
    """Before, the options were read after the env had been reseeded and laid out again."""
    env, twin = (gym.make("lerobot_ccdp/DoorOpening-lite-v0") for _ in range(2))
    for e in (env, twin):
        e.reset(seed=4)
        _steps(e)
    with pytest.raises(ValueError, match=named):
        env.reset(seed=5, options=options)
    np.testing.assert_array_equal(_steps(env), _steps(twin))
    assert env.unwrapped.hidden_param == twin.unwrapped.hidden_param


def test_an_action_that_is_not_numbers_is_refused_as_given():
    env = _make(task="DoorOpening-lite-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"finite action of shape \(4,\).*got 'left'"):
        env.step("left")


@pytest.mark.parametrize(
    "settings",
    [{"init_noise": "1e9"}, {"layout_noise": "nan"}, {"render_width": "320"}, {"max_failures": True}],
)
def test_an_env_setting_that_is_not_a_number_is_named(settings):
    """gym.make(id, init_noise="1e9") (YAML reads 1e9 as text) failed in numpy: "ufunc 'isfinite' not
    supported for the input types"."""
    with pytest.raises(
        ValueError, match=re.escape(f"{settings}: the attempt budget and image sizes are whole")
    ):
        gym.make("lerobot_ccdp/DoorOpening-lite-v0", **settings)


@pytest.mark.parametrize(
    "settings,named",
    [
        ({"obs_type": "pixels_agent_pos", "observation_width": 641}, "observation_width"),
        ({"render_height": 481}, "render_height"),
    ],
)
def test_an_image_larger_than_the_offscreen_buffer_is_refused_when_made(settings, named):
    """MuJoCo refused it at the first frame ("Image width 641 > framebuffer width 640 ... specify a larger
    offscreen framebuffer in the model XML"), for a video after the first episode's steps."""
    with pytest.raises(ValueError, match=rf"'{named}': \d+}}: images are rendered at most 640 wide and 480"):
        _make(task="DoorOpening-lite-v0", **settings)


def test_cameras_given_as_one_string_are_named_as_given():
    """Before: "got ['f', 'r', 'o', 'n', 't']"."""
    with pytest.raises(ValueError, match=r"cameras must name one or more of .* in a list, got 'front'"):
        gym.make("lerobot_ccdp/DoorOpening-lite-v0", obs_type="pixels_agent_pos", cameras="front")


def test_a_render_mode_the_env_cannot_serve_is_named_by_its_flag():
    """gymnasium wrapped --env.render_mode=human in a pygame window (headless: EGL errors at exit)."""
    with pytest.raises(ValueError, match=r"--env.render_mode must be rgb_array .* or null .*, got 'human'"):
        CCDPEnvConfig(task="DoorOpening-lite-v0", render_mode="human")
