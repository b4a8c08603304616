"""Checks on what lerobot-train is about to train a ccdp policy on, made before its first step.

LeRobot builds a fresh policy with the dataset's metadata (`make_policy` without `--policy.path`). Two
mistakes then go unnoticed by LeRobot: the recovery stage started without a base checkpoint trains a recovery
head over a random base, and a dataset whose episodes are all shorter than a chunk gives the sampler no frame,
so lerobot-train waits for its first batch forever. A third: `--resume=true` with a `--steps` the checkpoint
has already reached runs no step and exits 0, as if it had trained.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from lerobot.configs import parser
from lerobot.configs.train import TRAIN_CONFIG_NAME
from lerobot.utils.constants import TRAINING_STATE_DIR, TRAINING_STEP

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig


def refuse_fresh_training(config: CCDPConfig, dataset_meta: Any) -> None:
    """Refuse the recovery stage without a base, and a dataset with no window to train on."""
    if config.training_stage == "recovery":
        raise ValueError(
            "--policy.training_stage=recovery trains the recovery head on top of a trained base, but no base "
            "checkpoint was given, so the base would be random. Pass "
            "--policy.path=<base run>/checkpoints/last/pretrained_model instead of --policy.type=ccdp."
        )
    episodes = getattr(dataset_meta, "episodes", None)
    if episodes is None or "dataset_from_index" not in episodes.column_names:
        return
    lengths = [
        end - start
        for start, end in zip(episodes["dataset_from_index"], episodes["dataset_to_index"], strict=True)
    ]
    drop = config.drop_n_last_frames
    if not any(length > drop for length in lengths):
        raise ValueError(
            f"The dataset has no frame to train on: its {len(lengths)} episode(s) are at most "
            f"{max(lengths, default=0)} frames long, and a chunk can start only more than horizon - "
            f"n_action_steps - n_obs_steps + 1 = {drop} frames before an episode's end. Record longer "
            f"episodes, or lower --policy.horizon (a multiple of {2 ** len(config.down_dims)}) or raise "
            "--policy.n_action_steps."
        )


def refuse_resume_with_nothing_to_train(pretrained_path: str | Path | None) -> None:
    """Under `lerobot-train --resume=true`, refuse a `--steps` (the total, default: the resumed run's) that
    the checkpoint at `pretrained_path` (`<run>/checkpoints/<step>/pretrained_model`) has already reached:
    LeRobot's loop runs from the saved step to `--steps`, so it would train nothing. The command line is
    read as LeRobot's own config reads it on resume (`parser.parse_arg`); outside a resume this does
    nothing."""
    if pretrained_path is None or str(parser.parse_arg("resume")).lower() not in ("true", "yes", "1"):
        return
    model = Path(pretrained_path)
    step_file = model.parent / TRAINING_STATE_DIR / TRAINING_STEP
    if not step_file.is_file():
        return
    step = json.loads(step_file.read_text())["step"]
    steps = parser.parse_arg("steps")
    if steps is None and (model / TRAIN_CONFIG_NAME).is_file():
        steps = json.loads((model / TRAIN_CONFIG_NAME).read_text()).get("steps")
    if steps is not None and step >= int(steps):
        raise ValueError(
            f"--resume=true continues the checkpoint {model.parent}, saved at step {step}, and "
            f"--steps={steps} is the total number of steps, so nothing is left to train. Pass a larger "
            f"total, e.g. --steps={2 * step}."
        )
