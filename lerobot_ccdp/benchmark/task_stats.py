"""Benchmark of the five CCDP tasks: simulation speed, demo recording time, and the no-repeat oracle's
metrics.

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl python -m lerobot_ccdp.benchmark.task_stats [--tasks DoorOpening-v0 ...]

Prints one markdown table. Steps/s times `env.step` alone (expert actions, gymnasium wrappers included);
recording time is `lerobot-ccdp-record`'s work for `--record-episodes` episodes (dataset written to a
temporary folder); oracle figures are over `--episodes` seeded episodes with random hidden parameters.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
from lerobot.utils.utils import init_logging

from lerobot_ccdp.datasets.recipe_file import RecordRecipe
from lerobot_ccdp.datasets.record import record_dataset
from lerobot_ccdp.envs import TASKS, gym_id
from lerobot_ccdp.envs.scripted import Expert, NoRepeatOracle, run_episode


def steps_per_second(task: str, n_steps: int) -> float:
    env = gym.make(gym_id(task))
    expert = Expert(env)
    elapsed, steps, seed = 0.0, 0, 0
    while steps < n_steps:
        obs, info = env.reset(seed=seed)
        expert.reset()
        seed += 1
        done = False
        while not done:
            action = expert.act(obs, info)
            start = time.perf_counter()
            obs, _, terminated, truncated, info = env.step(action)
            elapsed += time.perf_counter() - start
            steps += 1
            done = terminated or truncated
    return steps / elapsed


def recording_seconds(task: str, n_episodes: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        record_dataset(
            RecordRecipe(task=task, n_episodes=n_episodes, seed=0),
            "local/bench",
            Path(tmp) / "ds",
            progress=False,
        )
        return time.perf_counter() - start


def oracle_metrics(task: str, n_episodes: int) -> dict[str, float]:
    env = gym.make(gym_id(task))
    oracle = NoRepeatOracle(env)
    infos = [run_episode(env, oracle, seed=10_000 + i).info for i in range(n_episodes)]
    successes = [i for i in infos if i["is_success"]]
    failures = sum(i["failures"] for i in infos)
    return {
        "success": len(successes) / n_episodes,
        "attempts": float(np.mean([i["attempts"] for i in successes])) if successes else float("nan"),
        "failures": failures / n_episodes,
        "repeated": sum(i["repeated_failures"] for i in infos) / max(failures, 1),
        "preference": float(np.mean([i["preference_matched"] for i in successes]))
        if successes
        else float("nan"),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=list(TASKS))
    parser.add_argument("--steps", type=int, default=5000, help="env steps timed per task")
    parser.add_argument("--record-episodes", type=int, default=100)
    parser.add_argument("--episodes", type=int, default=500, help="oracle episodes per task")
    args = parser.parse_args(argv)
    init_logging(console_level="WARNING")  # recording's progress lines would break the table

    print(
        f"| task | env steps/s | record {args.record_episodes} eps (s) | oracle success | oracle attempts "
        "(successes) | oracle failures/ep | repeated-failure rate | oracle preference adherence |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for task in args.tasks:
        sps = steps_per_second(task, args.steps)
        rec = recording_seconds(task, args.record_episodes)
        m = oracle_metrics(task, args.episodes)
        print(
            f"| {task} | {sps:,.0f} | {rec:.2f} | {m['success']:.3f} | {m['attempts']:.2f} "
            f"| {m['failures']:.2f} | {m['repeated']:.3f} | {m['preference']:.3f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
