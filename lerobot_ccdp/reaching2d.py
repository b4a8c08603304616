"""A synthetic 2-D multimodal reaching task: the smallest data on which failure recovery can be seen.

The agent starts near the origin and moves in a straight line to one of four goals, chosen with a fixed
preference (east most often, south least). One goal is "blocked" at run time in the recovery tests; a
policy that remembers the failure must then pick among the other three in their demonstrated proportions.
Used by the tests, the benchmarks and the README's train-on-a-local-dataset example.
"""

import argparse
import logging
from pathlib import Path

import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset

GOALS = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]], dtype=np.float32)
PREFERENCE = np.array([0.4, 0.3, 0.2, 0.1])
FPS = 10
REACH_STEPS = 20
HOLD_STEPS = 12

FEATURES = {
    "observation.state": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
    "action": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
    "primitive": {"dtype": "int64", "shape": (1,), "names": None},
}


def demo_episode(goal: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """States and target-position actions of one straight reach to GOALS[goal], then a hold."""
    start = rng.normal(0.0, 0.02, size=2).astype(np.float32)
    steps = REACH_STEPS + HOLD_STEPS
    progress = np.minimum(np.arange(1, steps + 1) / REACH_STEPS, 1.0)[:, None]
    actions = (start + progress * (GOALS[goal] - start)).astype(np.float32)
    states = np.concatenate([start[None], actions[:-1]]).astype(np.float32)
    return states, actions


def goal_of(positions: np.ndarray) -> np.ndarray:
    """Which goal each 2-D position is heading to (nearest goal direction)."""
    return np.argmax(positions @ GOALS.T, axis=-1)


def record_reaching_dataset(root: str | Path, repo_id: str = "local/reaching2d", n_episodes: int = 60, seed: int = 0) -> LeRobotDataset:
    """Write a LeRobot v3 dataset of demos whose goals follow PREFERENCE exactly in proportion."""
    rng = np.random.default_rng(seed)
    counts = np.round(PREFERENCE * n_episodes).astype(int)
    goals = rng.permutation(np.repeat(np.arange(len(GOALS)), counts))
    dataset = LeRobotDataset.create(repo_id, fps=FPS, features=FEATURES, root=root, use_videos=False)
    for goal in goals:
        states, actions = demo_episode(int(goal), rng)
        for state, action in zip(states, actions, strict=True):
            dataset.add_frame({
                "observation.state": state,
                "action": action,
                "primitive": np.array([goal], dtype=np.int64),
                "task": "reach a goal",
            })
        dataset.save_episode()
    dataset.finalize()
    return dataset


def main() -> None:
    """`python -m lerobot_ccdp.reaching2d --root data/reaching2d`: write the demo dataset for local training."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, required=True, help="where to write the dataset (must not exist)")
    parser.add_argument("--repo-id", default="local/reaching2d")
    parser.add_argument("--n-episodes", type=int, default=60)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    dataset = record_reaching_dataset(args.root, args.repo_id, args.n_episodes, args.seed)
    logging.info("Wrote %d episodes (%d frames) to %s", dataset.num_episodes, dataset.num_frames, args.root)


if __name__ == "__main__":
    main()


def chunks_after_failures(policy, preprocessor, postprocessor, failed_goals: list[int], rows: int, seed: int = 0):
    """Plan one chunk per row from the start state after reporting failures at `failed_goals` in every row.

    Returns the chunks in positions (rows, horizon, 2) and the goal each heads to, read from where the chunk
    ends (`goal_of`), not from the demonstrated-chunk labeller that DP* and the failure feature use, so the
    measurement behind the recovery tests and the Fig. 2 benchmark is independent of what it measures.
    """
    import torch

    from lerobot_ccdp.outcome_index import options_after_failures

    batch = preprocessor({"observation.state": torch.zeros(rows, 2)})
    chunks, _ = options_after_failures(policy, batch, failed_goals, seed)
    positions = postprocessor(chunks).reshape(rows, -1, 2).cpu()
    return positions, torch.from_numpy(goal_of(positions[:, -1].numpy()))


def shares_per_goal(goals):
    """Share of rows heading to each goal, from the goal indices `chunks_after_failures` returns."""
    import torch

    return torch.bincount(goals, minlength=len(GOALS)).float() / len(goals)
