"""Outcomes of demonstrated chunks, to give a sampled chunk the outcome of its nearest demonstrated one.

A chunk drawn from the diffusion model has no outcome of its own: nothing executed it. Its final state
and primitive are taken from the nearest demonstrated chunk (Euclidean distance in normalised action
space). The policy keeps this table in its state dict so a checkpoint is self-contained.
"""

import numpy as np
import torch
from torch import Tensor, nn


class OutcomeIndex(nn.Module):
    """Demonstrated chunks (M, horizon * action_dim) with their final states (M, z_dim) and primitives
    (M,)."""

    def __init__(self):
        super().__init__()
        self.register_buffer("chunks", torch.zeros(0, 0))
        self.register_buffer("final_states", torch.zeros(0, 0))
        self.register_buffer("primitives", torch.zeros(0, dtype=torch.long))

    def __len__(self) -> int:
        return self.chunks.shape[0]

    def fill(self, chunks: Tensor, final_states: Tensor, primitives: Tensor) -> None:
        self.chunks = chunks.flatten(start_dim=1).float()
        self.final_states = final_states.float()
        self.primitives = primitives.long()

    def nearest(self, chunk: Tensor) -> Tensor:
        """Index of the nearest demonstrated chunk for each chunk in (B, horizon, action_dim)."""
        return self._distances(chunk).argmin(dim=1)

    def nearest_end(self, state: Tensor) -> Tensor:
        """Index of the demonstrated frame whose option ends nearest each state (B, z_dim) (same dims as the
        table's final states)."""
        self._require_rows()
        return torch.cdist(state.float(), self.final_states).argmin(dim=1)

    def rms_distance(self, chunk: Tensor) -> Tensor:
        """Root-mean-square gap per action element between each chunk (B, horizon, action_dim) and its nearest
        demonstrated chunk: how far the outcome borrowed from that chunk is from being the chunk's own."""
        return self._distances(chunk).min(dim=1).values / chunk[0].numel() ** 0.5

    def _distances(self, chunk: Tensor) -> Tensor:
        self._require_rows()
        return torch.cdist(chunk.flatten(start_dim=1), self.chunks)

    def _require_rows(self) -> None:
        if len(self) == 0:
            raise RuntimeError(
                "This policy holds no demonstrated outcomes, so a sampled chunk's final state or primitive "
                "is unknown. Train the base stage from a dataset (lerobot-train builds the table), or use "
                "--policy.failure_feature=action."
            )

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # The table's size depends on the dataset it was built from: take the saved shapes.
        for name in ("chunks", "final_states", "primitives"):
            if prefix + name in state_dict:
                setattr(self, name, torch.empty_like(state_dict[prefix + name]))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)


def options_after_failures(policy, batch: dict[str, Tensor], failed_options: list[int], seed: int = 0):
    """Plan one chunk per row of `batch` (normalised observations) after reporting failures at
    `failed_options` in every row; returns the chunks (rows, horizon, A) and the option of each (its nearest
    demonstrated chunk's primitive). The measurement behind the recovery tests and the option-share
    benchmarks."""
    torch.manual_seed(seed)
    policy.reset()
    policy.select_action(batch)
    rows = batch["observation.state"].shape[0]
    for option in failed_options:
        policy.report_failure(z=policy.model.feature.one_hot(torch.full((rows,), option)))
    policy.select_action(batch)
    chunks = policy._rollout.memory.attempt_chunk
    return chunks, policy.model.outcomes.primitives[policy.model.outcomes.nearest(chunks)]


def demo_chunks(episode_index: np.ndarray, actions: np.ndarray, start: int, horizon: int) -> np.ndarray:
    """The chunk each frame starts, actions[t + start : t + start + horizon], clamped inside its episode.

    This is how LeRobotDataset pads chunks at episode edges (copies of the edge frame), so the table holds
    the same chunks the policy was trained on.
    """
    n = len(actions)
    first, last = episode_bounds(episode_index)
    offsets = np.arange(n)[:, None] + start + np.arange(horizon)[None, :]
    offsets = np.clip(offsets, first[:, None], last[:, None])
    return actions[offsets]


def episode_bounds(episode_index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last frame index of the episode each frame belongs to (frames sorted by episode)."""
    change = np.flatnonzero(np.diff(episode_index)) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change - 1, [len(episode_index) - 1]])
    which = np.searchsorted(starts, np.arange(len(episode_index)), side="right") - 1
    return starts[which], ends[which]
