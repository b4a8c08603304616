"""Failure key features z (paper III-B.1), computed the same way by the policy and the recovery recipe.

z always lives in the normalised space of its source: `final_state` takes dims of the normalised state
frame (robot state, then env state), `action` the normalised chunk, `primitive` a one-hot label. A recovery
dataset stores z in raw units under FAILURE_FEATURE_KEY with the stats from `failure_feature_stats`, so
LeRobot's normaliser maps stored z onto exactly the values the policy computes at run time.
"""

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from torch import Tensor

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.observations import vector_keys
from lerobot_ccdp.policy.outcome_index import OutcomeIndex


class FailureFeature:
    """z(a, x) for the choice made in the config."""

    def __init__(self, config: CCDPConfig):
        self.config = config
        self.kind = config.failure_feature
        self.dim = config.failure_feature_dim

    def state_dims(self) -> Tensor:
        """Indices of the z dims within the policy's observation frame (robot state, then env state)."""
        return torch.tensor(state_dims(self.config), dtype=torch.long)

    def from_frame(self, frame: Tensor) -> Tensor:
        """final_state z from normalised observation frames (..., state_dim)."""
        return frame[..., self.state_dims().to(frame.device)]

    def from_chunk(self, chunk: Tensor, outcomes: OutcomeIndex) -> Tensor:
        """z of normalised action chunks (B, horizon, action_dim).

        `action` reads the chunk itself. A sampled chunk has no outcome of its own, so `final_state` and
        `primitive` take the outcome of the nearest demonstrated chunk.
        """
        if self.kind == "action":
            return chunk.flatten(start_dim=1)
        nearest = outcomes.nearest(chunk)
        if self.kind == "final_state":
            return outcomes.final_states[nearest]
        return self.one_hot(outcomes.primitives[nearest])

    def of_failure(
        self, frame_at_failure: Tensor, attempt_chunk: Tensor, latest_chunk: Tensor, outcomes: OutcomeIndex
    ) -> Tensor:
        """z_f of failed attempts: the state where the attempt ended (`final_state` at "attempt_end") or the
        final state of the demonstration it was following ("demonstrated_end"), the attempt's first chunk, the
        one that chose the option (`action`), or the label of the chunk executing when the failure was flagged
        (`primitive`). A label is a property of the whole attempt, and the latest chunk, near where the
        attempt failed, names it far more reliably than the first, whose steps are mostly the approach that
        every option shares (ButtonSearch: 0.99 vs 0.75 of failures given their true option, under DP*).
        With `failure_label_at="attempt_end"` the label is that of the demonstrated option ending nearest the
        state where the attempt stopped: a chunk that finished one option and failed the next (the Bartender's
        pour into the next cup) is named for the option it failed, not the one it began with."""
        if self.kind == "primitive" and self.reads_failure_frame:
            return self.one_hot(outcomes.primitives[outcomes.nearest_end(self.from_frame(frame_at_failure))])
        if self.reads_failure_frame:
            return self.from_frame(frame_at_failure)
        return self.from_chunk(attempt_chunk if self.kind == "action" else latest_chunk, outcomes)

    @property
    def reads_failure_frame(self) -> bool:
        """Whether a failure's z comes from the observed state, so an attempt that planned no chunk has
        one."""
        cfg = self.config
        if self.kind == "primitive":
            return cfg.failure_label_at == "attempt_end"
        return self.kind == "final_state" and cfg.failure_state_at == "attempt_end"

    def one_hot(self, labels: Tensor) -> Tensor:
        return F.one_hot(labels.long(), self.config.num_primitives).to(torch.float32)


def failure_feature_stats(config: CCDPConfig, source_stats: dict[str, dict]) -> dict[str, np.ndarray]:
    """Stats for FAILURE_FEATURE_KEY that make normalising a raw z equal to z computed from normalised data.

    `source_stats` are the demo dataset's stats (LeRobot's `meta.stats`). final_state z slices the state
    frame's stats, action z tiles the action stats once per step of the chunk, and the one-hot primitive z
    gets stats under which both MEAN_STD and MIN_MAX leave it unchanged.
    """
    kind = config.failure_feature
    if kind == "primitive":
        n = config.num_primitives
        return {
            "mean": np.zeros(n),
            "std": np.ones(n),
            "min": -np.ones(n),
            "max": np.ones(n),
        }
    names = ("mean", "std", "min", "max")
    if kind == "final_state":
        frame = {
            k: np.concatenate([np.asarray(source_stats[key][k]).reshape(-1) for key in vector_keys(config)])
            for k in names
        }
        return {k: v[state_dims(config)] for k, v in frame.items()}
    return {k: np.tile(np.asarray(source_stats["action"][k]), config.horizon) for k in names}


def state_dims(config: CCDPConfig) -> list[int]:
    """The final_state z dims within the state frame (robot state, then env state): `failure_state_dims`,
    or every robot-state dim."""
    return list(config.failure_state_dims) or list(range(config.robot_state_feature.shape[0]))
