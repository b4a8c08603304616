"""Checks on what lerobot-train is about to train a fresh ccdp policy on, made before its first step.

LeRobot builds a fresh policy with the dataset's metadata (`make_policy` without `--policy.path`). Two
mistakes then go unnoticed by LeRobot: the recovery stage started without a base checkpoint trains a recovery
head over a random base, and a dataset whose episodes are all shorter than a chunk gives the sampler no frame,
so lerobot-train waits for its first batch forever.
"""

from __future__ import annotations

from typing import Any

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
