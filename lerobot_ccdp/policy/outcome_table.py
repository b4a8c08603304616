"""Builds the policy's table of demonstrated chunk outcomes from a LeRobot demo dataset."""

import numpy as np
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.utils.constants import ACTION
from torch import Tensor

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.demo_segments import segment_ends, segment_final_states
from lerobot_ccdp.policy.failure_features import state_dims
from lerobot_ccdp.policy.observations import refuse_non_finite_stats, vector_keys
from lerobot_ccdp.policy.outcome_index import demo_chunks
from lerobot_ccdp.policy.processor_ccdp import normalize_batch

# Demonstrated chunks kept to look up the outcome of a sampled chunk (a random subset beyond it).
OUTCOME_TABLE_SIZE = 20000


def build_outcome_table(
    config: CCDPConfig, meta: LeRobotDatasetMetadata, stats: dict | None
) -> tuple[Tensor, Tensor, Tensor]:
    """(chunks, final-state z, primitive labels) of demonstrated frames, in the policy's normalised space.
    Every frame goes in, not only those training draws, so every frame and the stats are checked finite
    (`read_columns`)."""
    keys = vector_keys(config)
    required = [ACTION, *keys]
    if config.failure_feature == "primitive":
        required.append(config.primitive_key)
    columns = read_columns(meta, required, optional=[config.primitive_key])
    stats = stats or meta.stats
    refuse_non_finite_stats(config, stats)
    normalized = normalize_batch(
        config, stats, {key: torch.from_numpy(columns[key]) for key in [ACTION, *keys]}
    )
    episodes, primitives = columns["episode_index"], columns.get(config.primitive_key)
    chunks = demo_chunks(episodes, normalized[ACTION].numpy(), 1 - config.n_obs_steps, config.horizon)
    ends = segment_ends(config.failure_segments, episodes, normalized[ACTION].numpy(), primitives)
    frames = torch.cat([normalized[key] for key in keys], dim=-1).numpy()
    finals = segment_final_states(frames, ends)[:, state_dims(config)]
    labels = (
        np.zeros(len(chunks), dtype=np.int64)
        if primitives is None
        else primitives.reshape(-1).astype(np.int64)
    )
    if config.failure_feature == "primitive" and labels.max() >= config.num_primitives:
        raise ValueError(
            f"Column {config.primitive_key!r} holds label {labels.max()}, but num_primitives is "
            f"{config.num_primitives}; set --policy.num_primitives={labels.max() + 1}."
        )
    keep = np.sort(np.random.default_rng(0).permutation(len(chunks))[:OUTCOME_TABLE_SIZE])
    return torch.from_numpy(chunks[keep]), torch.from_numpy(finals[keep]), torch.from_numpy(labels[keep])


def read_columns(
    meta: LeRobotDatasetMetadata, required: list[str], optional: list[str] = ()
) -> dict[str, np.ndarray]:
    """Whole columns of a local LeRobot dataset as float32 arrays (frames in episode order). A NaN or inf in
    any of them is refused, naming its episode and frame: the dataset's stats.json may predate it, and a
    frame no training batch draws would otherwise reach the outcome table unseen."""
    missing = [k for k in required if k not in meta.features]
    if missing:
        raise ValueError(
            f"Dataset {meta.repo_id!r} at {meta.root} lacks column(s) {missing} (it has "
            f"{sorted(meta.features)}). Record it with the needed features, or change the policy's failure "
            "feature settings."
        )
    keys = list(dict.fromkeys([*required, *(k for k in optional if k in meta.features)]))
    read = list(dict.fromkeys([*keys, "episode_index", "frame_index"]))
    # one batch read of these columns only: row by row, `datasets` formats every frame on its own
    hf = LeRobotDataset(meta.repo_id, root=meta.root).hf_dataset
    data = hf.select_columns(read).with_format("numpy")[:]
    out = {k: np.stack(data[k]).astype(np.float32) for k in keys}
    out["episode_index"] = np.asarray(data["episode_index"]).reshape(-1)
    for key in keys:
        bad = ~np.isfinite(out[key].reshape(len(out[key]), -1)).all(axis=1)
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            raise ValueError(
                f"Dataset {meta.repo_id!r} at {meta.root} holds NaN or inf in column {key!r} at episode "
                f"{out['episode_index'][first]}, frame {np.asarray(data['frame_index']).reshape(-1)[first]} "
                f"({int(bad.sum())} frame(s) in all). Remove or re-record those episodes, then recompute "
                "the dataset's stats."
            )
    return out
