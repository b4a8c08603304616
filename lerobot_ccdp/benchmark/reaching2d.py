"""Synthetic 2-D multimodal reaching tasks: the smallest data on which failure recovery can be seen.

The agent starts near the origin and moves to one of several goals, chosen with a fixed preference. The
default task has four goals on straight paths (east most often, south least);
`ReachingTask.family_member(seed)` draws the seeded family of issue 17 (3 to 6 goals at random angles, random
preferences, bent paths, with or without option labels). A goal is "blocked" at run time in the recovery
tests; a policy that remembers the failure must then pick among the other goals in their demonstrated
proportions.
Used by the tests, the benchmarks and the README's train-on-a-local-dataset example.
"""

import argparse
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_ccdp.datasets.staging import check_output_root, staged_dataset_root

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


@dataclass(frozen=True)
class ReachingTask:
    """A 2-D reaching task: goals on the unit circle, a preference over them, paths bent sideways by `bend` (a
    fraction of the reach, 0 for straight lines), with or without the goal's `primitive` label in the
    dataset."""

    goals: np.ndarray
    preference: np.ndarray
    bend: float = 0.0
    labelled: bool = True

    @classmethod
    def family_member(cls, seed: int) -> "ReachingTask":
        """The seeded family of issue 17: 3 to 6 goals at random angles at least 45 degrees apart, random
        preferences (Dirichlet, none under 0.05), random bends; even seeds carry labels, odd seeds do not."""
        rng = np.random.default_rng(seed)
        k = int(rng.integers(3, 7))
        while True:
            angles = np.sort(rng.uniform(0, 2 * np.pi, k))
            if np.diff(np.append(angles, angles[0] + 2 * np.pi)).min() >= np.pi / 4:
                break
        preference = np.maximum(rng.dirichlet(np.full(k, 2.0)), 0.05)
        goals = np.stack([np.cos(angles), np.sin(angles)], axis=1).astype(np.float32)
        return cls(goals, preference / preference.sum(), float(rng.uniform(-0.4, 0.4)), seed % 2 == 0)

    @property
    def features(self) -> dict:
        return FEATURES if self.labelled else {k: v for k, v in FEATURES.items() if k != "primitive"}

    def path(self, goal: int, start: np.ndarray, progress: np.ndarray) -> np.ndarray:
        """Positions (T, 2) at `progress` (T,) in [0, 1] along the bent reach from `start` to goal `goal`."""
        reach = self.goals[goal] - start
        side = np.array([-reach[1], reach[0]])
        p = progress[:, None]
        return start + p * reach + self.bend * np.sin(np.pi * p) * side

    def demo_episode(self, goal: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """States and target-position actions of one reach to goal `goal`, then a hold."""
        start = rng.normal(0.0, 0.02, size=2).astype(np.float32)
        progress = np.minimum(np.arange(1, REACH_STEPS + HOLD_STEPS + 1) / REACH_STEPS, 1.0)
        actions = self.path(goal, start, progress).astype(np.float32)
        states = np.concatenate([start[None], actions[:-1]]).astype(np.float32)
        return states, actions

    def option_of(self, chunks: np.ndarray) -> np.ndarray:
        """The goal each planned chunk of positions (R, T, 2), started at the origin, heads to: the goal whose
        demonstrated path from the origin it is nearest to."""
        return self.path_distances(chunks).argmin(axis=1)

    def path_distances(self, chunks: np.ndarray) -> np.ndarray:
        """Squared distance (R, K) of each planned chunk of positions (R, T, 2), started at the origin, to
        each goal's demonstrated path over the same steps."""
        progress = np.minimum(np.arange(1, chunks.shape[1] + 1) / REACH_STEPS, 1.0)
        paths = np.stack([self.path(g, np.zeros(2), progress) for g in range(len(self.goals))])  # (K, T, 2)
        return ((chunks[:, None] - paths[None]) ** 2).sum(axis=(2, 3))

    def record(self, root: str | Path, repo_id: str, n_episodes: int, seed: int = 0) -> LeRobotDataset:
        """Write a LeRobot v3 dataset of demos whose goals follow the preference in proportion (rounded)."""
        rng = np.random.default_rng(seed)
        counts = np.maximum(np.round(self.preference * n_episodes).astype(int), 1)
        goals = rng.permutation(np.repeat(np.arange(len(self.goals)), counts))
        dataset = LeRobotDataset.create(repo_id, fps=FPS, features=self.features, root=root, use_videos=False)
        for goal in goals:
            states, actions = self.demo_episode(int(goal), rng)
            for state, action in zip(states, actions, strict=True):
                frame = {"observation.state": state, "action": action, "task": "reach a goal"}
                if self.labelled:
                    frame["primitive"] = np.array([goal], dtype=np.int64)
                dataset.add_frame(frame)
            dataset.save_episode()
        dataset.finalize()
        return dataset


FOUR_GOALS = ReachingTask(GOALS, PREFERENCE)


def demo_episode(goal: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """States and target-position actions of one straight reach to GOALS[goal], then a hold."""
    return FOUR_GOALS.demo_episode(goal, rng)


def goal_of(positions: np.ndarray) -> np.ndarray:
    """Which goal each 2-D position is heading to (nearest goal direction)."""
    return np.argmax(positions @ GOALS.T, axis=-1)


def record_reaching_dataset(
    root: str | Path, repo_id: str = "local/reaching2d", n_episodes: int = 60, seed: int = 0
) -> LeRobotDataset:
    """Write a LeRobot v3 dataset of demos whose goals follow PREFERENCE exactly in proportion."""
    return FOUR_GOALS.record(root, repo_id, n_episodes, seed)


def main(argv: list[str] | None = None) -> None:
    """`python -m lerobot_ccdp.benchmark.reaching2d --root data/reaching2d`: write the demo dataset for local
    training (built beside `--root` and renamed into place, as lerobot-ccdp-record's)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--root", type=Path, required=True, help="where to write the dataset: a new or empty folder"
    )
    parser.add_argument("--repo-id", default="local/reaching2d")
    parser.add_argument("--n-episodes", type=int, default=60)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--overwrite", action="store_true", help="replace a dataset this command wrote at --root"
    )
    args = parser.parse_args(argv)
    try:
        check_output_root(args.root, args.overwrite, "--overwrite")
    except (OSError, ValueError) as error:
        parser.error(str(error))
    logging.basicConfig(level=logging.INFO)
    with staged_dataset_root(args.root, args.overwrite, "--overwrite") as staging:
        dataset = record_reaching_dataset(staging, args.repo_id, args.n_episodes, args.seed)
    logging.info("Wrote %d episodes (%d frames) to %s", dataset.num_episodes, dataset.num_frames, args.root)


if __name__ == "__main__":
    main()


def chunks_after_failures(
    policy, preprocessor, postprocessor, failed_goals: list[int], rows: int, seed: int = 0
):
    """Plan one chunk per row from the start state after reporting failures at `failed_goals` in every row.

    Returns the chunks in positions (rows, horizon, 2) and the goal each heads to, read from where the chunk
    ends (`goal_of`), not from the demonstrated-chunk labeller that DP* and the failure feature use, so the
    measurement behind the recovery tests and the Fig. 2 benchmark is independent of what it measures.
    """
    import torch

    from lerobot_ccdp.policy.outcome_index import options_after_failures

    batch = preprocessor({"observation.state": torch.zeros(rows, 2)})
    chunks, _ = options_after_failures(policy, batch, failed_goals, seed)
    positions = postprocessor(chunks).reshape(rows, -1, 2).cpu()
    return positions, torch.from_numpy(goal_of(positions[:, -1].numpy()))


def shares_per_goal(goals):
    """Share of rows heading to each goal, from the goal indices `chunks_after_failures` returns."""
    import torch

    return torch.bincount(goals, minlength=len(GOALS)).float() / len(goals)
