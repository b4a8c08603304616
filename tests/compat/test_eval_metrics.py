"""lerobot-eval's episode order and the env's final info: what eval_metrics adds to eval_info.json."""

import gymnasium as gym
import numpy as np
from lerobot.envs.factory import make_env
from lerobot.scripts import lerobot_eval

from lerobot_ccdp.compat.eval_metrics import EPISODE_INFO_KEYS, EpisodeInfoRecorder, is_ccdp_env
from lerobot_ccdp.envs import CCDPEnvConfig, gym_id
from lerobot_ccdp.envs.scripted import NoRepeatOracle, run_episode

TASK = "ButtonSearch-lite-v0"


def _oracle_batch(vec: gym.vector.VectorEnv, seeds: list[int]) -> None:
    """Step every sub-env with its own no-repeat oracle until all are done, as lerobot-eval's rollout does."""
    observation, info = vec.reset(seed=seeds)
    agents = [NoRepeatOracle(env) for env in vec.envs]
    done = np.zeros(vec.num_envs, dtype=bool)
    while not done.all():
        actions = np.stack(
            [
                agent.act({k: v[i] for k, v in observation.items()}, {"option": info["option"][i]})
                for i, agent in enumerate(agents)
            ]
        )
        observation, _, terminated, truncated, info = vec.step(actions)
        done |= terminated | truncated


def test_recorder_keeps_every_episodes_final_info_in_eval_order():
    vec = make_env(CCDPEnvConfig(task=TASK, render_mode=None), n_envs=3)["ccdp"][0]
    recorder = EpisodeInfoRecorder(vec)
    seeds = [[100, 101, 102], [103, 104, 105]]
    for batch in seeds:
        _oracle_batch(vec, batch)
    recorder.detach()
    metrics = recorder.metrics(5)  # lerobot-eval drops the surplus episodes of the last batch

    env = gym.make(gym_id(TASK))
    expected = [run_episode(env, NoRepeatOracle(env), seed=s).info for s in [*seeds[0], *seeds[1]][:5]]
    assert set(metrics) == set(EPISODE_INFO_KEYS)
    for key in EPISODE_INFO_KEYS:
        assert metrics[key] == [info[key] for info in expected], key
    assert max(metrics["attempts"]) > 1  # the hidden button was not always the first one tried
    assert vec.step.__self__ is not recorder  # detached: the env steps on its own again
    vec.close()


def test_eval_one_is_wrapped_once_a_ccdp_env_is_configured():
    CCDPEnvConfig(task="DoorOpening-lite-v0")
    assert getattr(lerobot_eval.eval_one, "_ccdp_episode_metrics", False)


def test_other_envs_are_left_to_lerobot():
    vec = gym.vector.SyncVectorEnv([lambda: gym.make("CartPole-v1")])
    assert not is_ccdp_env(vec)
    vec.close()
