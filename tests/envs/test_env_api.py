"""Gymnasium API, seeding and observation contracts of the five tasks."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from lerobot_ccdp.envs import TASKS, task_class
from lerobot_ccdp.envs.scripted import Expert, run_episode

from env_helpers import make

ALL = list(TASKS)


@pytest.mark.parametrize("task", ALL)
def test_gymnasium_env_checker(task):
    env = make(task, render_mode="rgb_array", disable_env_checker=True)
    check_env(env.unwrapped)
    env.close()


@pytest.mark.parametrize("task", ALL)
def test_observation_keys_dtypes_and_action_space(task):
    env = make(task)
    obs, info = env.reset(seed=0)
    assert set(obs) == {"agent_pos", "environment_state", "failure"}
    assert all(v.dtype == np.float32 for v in obs.values())
    assert obs["agent_pos"].shape == (4,)
    assert obs["environment_state"].shape == (len(task_class(task).env_state_names),)
    assert obs["failure"].tolist() == [0.0]
    assert env.action_space.shape == (4,) and env.action_space.dtype == np.float32
    assert info == {
        "is_success": False,
        "attempts": 0,
        "failures": 0,
        "repeated_failures": 0,
        "attempts_after_failure": 0,
        "preference_matched": False,
        "option": -1,
    }


@pytest.mark.parametrize("task", ALL)
def test_same_seed_same_rollout(task):
    env = make(task)
    first, second = (run_episode(env, Expert(env), seed=7) for _ in range(2))
    assert first.hidden_param == second.hidden_param
    assert len(first.actions) == len(second.actions)
    for a, b in zip(first.observations, second.observations, strict=True):
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])


@pytest.mark.parametrize("task", ALL)
def test_seeds_change_layout_and_hidden_parameter(task):
    env = make(task)
    resets = [env.reset(seed=s)[0]["environment_state"] for s in range(2)]
    assert not np.array_equal(*resets)
    hidden = set()
    for s in range(40):
        env.reset(seed=s)
        hidden.add(env.unwrapped.hidden_param)
    assert len(hidden) > 1


@pytest.mark.parametrize("task", ALL)
def test_reset_observation_does_not_depend_on_hidden_parameter(task):
    env = make(task)
    values = env.unwrapped.hidden_values()
    assert len(values) > 1
    reference = env.reset(seed=3, options={"hidden_param": values[0]})[0]
    for value in values[1:]:
        obs = env.reset(seed=3, options={"hidden_param": value})[0]
        assert env.unwrapped.hidden_param == value
        for key in obs:
            np.testing.assert_array_equal(obs[key], reference[key])


def test_invalid_hidden_parameter_is_rejected():
    env = make("ButtonSearch-lite-v0")
    with pytest.raises(ValueError, match="hidden_param 9 not in"):
        env.reset(seed=0, options={"hidden_param": 9})


def test_unknown_task_names_the_known_ones():
    with pytest.raises(
        ValueError, match="known tasks: DoorOpening-v0, ButtonSearch-v0, ObjectManipulation-v0"
    ):
        task_class("Door-v0")


@pytest.mark.parametrize("task", ALL)
def test_registered_step_limit_truncates(task):
    env = gym.make(f"lerobot_ccdp/{task}", max_episode_steps=5)
    obs, _ = env.reset(seed=0)
    hold = np.array([*obs["agent_pos"][:3], obs["agent_pos"][3]], dtype=np.float32)
    for step in range(5):
        _, reward, terminated, truncated, info = env.step(hold)
        assert not terminated and reward == 0.0
        assert truncated == (step == 4)
    assert info["is_success"] is False


@pytest.mark.parametrize("task", ALL)
def test_render_returns_rgb_frames(task):
    env = make(task, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8 and frame.std() > 0
    env.close()
    no_render = make(task)
    no_render.reset(seed=0)
    assert no_render.render() is None
