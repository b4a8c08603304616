"""lerobot-eval's episode order and the env's final info: what eval_metrics adds to eval_info.json; what
lerobot-eval prints per mode, and the folder it names for the mode."""

import logging
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from lerobot.envs.factory import make_env
from lerobot.scripts import lerobot_eval

from lerobot_ccdp.benchmark.comparison import METHOD_LABELS, METRIC_LABELS, MethodMetrics
from lerobot_ccdp.benchmark.episodes import Episodes
from lerobot_ccdp.compat.eval_metrics import EPISODE_INFO_KEYS, EpisodeInfoRecorder, is_ccdp_env, summary
from lerobot_ccdp.envs import CCDPEnvConfig, gym_id
from lerobot_ccdp.envs.scripted import NoRepeatOracle, run_episode

from fixtures.eval_runs import episodes
from fixtures.lite_eval import DOOR_LITE, run_lerobot_eval

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


@pytest.fixture
def lerobot_eval_in(tmp_path, monkeypatch, capsys):
    """Run `lerobot-eval` (its console entry point, in-process) from `tmp_path` on the door checkpoint; return
    its console output. LeRobot's init_logging replaces the root logger's handlers: they are put back."""
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    monkeypatch.chdir(tmp_path)

    def run(checkpoint: Path, *flags: str) -> str:
        run_lerobot_eval(
            monkeypatch,
            checkpoint,
            DOOR_LITE,
            "--env.episode_length=60",
            "--eval.n_episodes=2",
            "--eval.batch_size=2",
            *flags,
        )
        captured = capsys.readouterr()
        return captured.out + captured.err

    yield run
    root.handlers[:], root.level = handlers, level


def _printed_rows(console: str, mode: str) -> list[list[str]]:
    """The lines under the console's "Mode <mode> ..." heading, each split at its label's padding."""
    lines = console.splitlines()
    start = next(i for i, line in enumerate(lines) if f" Mode {mode} (" in line)
    rows = []
    for line in lines[start + 1 :]:
        if not line.startswith("  "):
            break
        rows.append(re.split(r"\s{2,}", line.strip()))
    return rows


@pytest.mark.parametrize("mode", ["ccdp", "dp", "dp_star"])
def test_the_console_says_what_the_results_table_says_and_the_folder_names_the_mode(
    door_lite_checkpoint, lerobot_eval_in, tmp_path, mode
):
    """Before, one line, "repeated-failure rate 0.154" (the per-attempt rate), no mode, and every mode's
    folder `<time>_ccdp_ccdp`."""
    console = lerobot_eval_in(door_lite_checkpoint, f"--policy.recovery_mode={mode}")

    (folder,) = (tmp_path / "outputs" / "eval").glob("*/*")
    assert re.fullmatch(rf"\d\d-\d\d-\d\d_ccdp_ccdp_{mode}", folder.name)
    assert f"No job name provided, using 'ccdp_ccdp_{mode}' as job name." in console
    assert "using 'ccdp_ccdp' as job name" not in console
    episodes = Episodes.from_eval_info(folder / "eval_info.json")
    row = MethodMetrics.of(episodes)
    assert f" Mode {mode} ({METHOD_LABELS[mode]}) on {DOOR_LITE}, 2 episodes, as the results table" in console
    *metrics, counts = _printed_rows(console, mode)
    assert dict(metrics) == {label: str(getattr(row, name)) for name, label in METRIC_LABELS.items()}
    attempts, failures, after, repeats = (
        int(getattr(episodes, key).sum())
        for key in ("attempts", "failures", "attempts_after_failure", "repeated_failures")
    )
    assert counts == [
        f"attempts {attempts}, failures {failures}, attempts after a failure {after}, "
        f"repeated failures {repeats}"
    ]
    assert failures > 0  # the untrained policy fails attempts: the counts are not all zero


def test_the_console_gives_repeats_per_attempt_after_a_failure_not_per_attempt():
    """60 of 100 episodes solved, each of 3 attempts, 2 of them after a failure; 20 repeat one: 20 / 200
    repeats per attempt after a failure (the table's), against 20 / 300 per attempt."""
    found = episodes(successes=60, repeats=20)
    metrics = {"successes": found.success.tolist()} | {
        key: getattr(found, key).tolist() for key in EPISODE_INFO_KEYS
    }
    printed = summary(metrics, "ccdp", DOOR_LITE)
    assert "repeats per attempt after a failure  0.10 [" in printed
    assert "repeated-failure rate (per attempt)  0.07 [" in printed
    assert printed.endswith("attempts 300, failures 100, attempts after a failure 200, repeated failures 20")
