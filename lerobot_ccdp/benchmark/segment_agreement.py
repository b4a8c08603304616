"""How often a label-free segment ends where the demonstrated option ends (issue 17: `final_state` z without
labels).

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl python -m lerobot_ccdp.benchmark.segment_agreement [--tasks all]
        [--episodes 100]

Records `--episodes` demonstrations of each task with its recipe (as lerobot-ccdp-record, into a fresh
temporary folder), then gives every frame the state its option reaches under each of
`demo_segments.SEGMENT_RULES` with the labels hidden (`labels` then means the episode's end, today's
label-free form) and compares it with the end of the frame's labelled option (the recorded `primitive` column,
which the policy never reads here). Prints one markdown table: the share of frames whose label-free end lies
within `--tolerance` metres (pinch point x, y) of their labelled end, and the segments per episode. A rule
that splits an option (a grasp on the way to a crate) or merges two (a whole episode of two fills) scores low.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_ccdp.benchmark.pipeline import expand_tasks, task_slug
from lerobot_ccdp.datasets.recipe_file import RecordRecipe
from lerobot_ccdp.datasets.record import record_dataset
from lerobot_ccdp.policy.demo_segments import SEGMENT_RULES, segment_ends, segment_final_states
from lerobot_ccdp.policy.outcome_table import read_columns

RECIPES = Path("datasets_recipes")  # the repository's, run from its root
PINCH_XY = [0, 1]  # observation.state: pinch point x, y, z, closure


def agreement(columns: dict[str, np.ndarray], rule: str, tolerance: float) -> tuple[float, float]:
    """(share of frames whose end under `rule` is within `tolerance` of the labelled end, segments per
    episode)."""
    episodes, states, actions = columns["episode_index"], columns[OBS_STATE][:, PINCH_XY], columns[ACTION]
    labelled = segment_final_states(states, segment_ends("labels", episodes, actions, columns["primitive"]))
    ends = segment_ends(rule, episodes, actions)
    found = segment_final_states(states, ends)
    close = np.linalg.norm(found - labelled, axis=1) <= tolerance
    return float(close.mean()), ends.sum() / len(np.unique(episodes))


def record(task: str, root: Path, episodes: int) -> dict[str, np.ndarray]:
    """`episodes` demos of `task` recorded with its recipe's settings, as lerobot-ccdp-record records them."""
    slug = task_slug(task)
    recipe = dataclasses.replace(RecordRecipe.load(RECIPES / f"{slug}.yaml"), n_episodes=episodes)
    record_dataset(recipe, f"local/{slug}", root, progress=False)
    return read_columns(LeRobotDatasetMetadata(f"local/{slug}", root=root), [OBS_STATE, ACTION, "primitive"])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--tasks", nargs="+", default=["all"])
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--tolerance", type=float, default=0.02, help="metres, pinch point x, y")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for task in expand_tasks(args.tasks):
            columns = record(task, Path(tmp) / task, args.episodes)
            cells = [agreement(columns, rule, args.tolerance) for rule in SEGMENT_RULES]
            rows.append(
                f"| {task} | " + " | ".join(f"{share:.2f} ({per:.1f})" for share, per in cells) + " |"
            )
    header = " | ".join(f"`{r}`" + (" (episode end)" if r == "labels" else "") for r in SEGMENT_RULES)
    print(
        f"\nFrames whose label-free end is within {args.tolerance} m of their labelled option's end "
        f"(segments per episode), {args.episodes} demonstrations per task:\n"
    )
    print(f"| task | {header} |\n|---|" + "---|" * len(SEGMENT_RULES))
    print("\n".join(rows))


if __name__ == "__main__":
    main()
