"""What the policy remembers during a rollout, per batch row: recent frames, executed actions, the plan."""

import logging

import torch
from torch import Tensor

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.failure_buffer import FailureBuffer, ordinary_tensors
from lerobot_ccdp.policy.failure_features import FailureFeature
from lerobot_ccdp.policy.outcome_index import OutcomeIndex
from lerobot_ccdp.policy.samplers import PlanRows, row_generators

logger = logging.getLogger(__name__)

# Most failures remembered per batch row (the oldest is forgotten beyond it).
MAX_FAILURES = 8


class RolloutMemory:
    """Per-row windows of observations and executed actions, the current plan, and two chunks of the attempt:
    its first (the one that chose the option) and its latest (the one executing when a failure is flagged).

    Every row moves on its own clock: a row that fails is restarted (its windows refilled with the current
    frame, as at an episode start, and its plan dropped) while the other rows keep executing their plans.
    """

    @ordinary_tensors
    def __init__(self, config: CCDPConfig, batch_size: int, device: torch.device):
        self.n_obs, self.history = config.n_obs_steps, config.history_length
        window = self.history + self.n_obs
        self.frames = torch.zeros(batch_size, window, config.frame_dim, device=device)
        self.actions = torch.zeros(batch_size, window - 1, config.action_dim, device=device)
        self.plan = torch.zeros(batch_size, config.n_action_steps, config.action_dim, device=device)
        self.plan_pos = torch.full((batch_size,), config.n_action_steps, dtype=torch.long, device=device)
        self.attempt_chunk = torch.zeros(batch_size, config.horizon, config.action_dim, device=device)
        self.latest_chunk = torch.zeros(batch_size, config.horizon, config.action_dim, device=device)
        self.attempt_planned = torch.zeros(batch_size, dtype=torch.bool, device=device)
        self.started = torch.zeros(batch_size, dtype=torch.bool, device=device)
        self.restart_pending = torch.zeros(batch_size, dtype=torch.bool, device=device)

    @property
    def batch_size(self) -> int:
        return self.frames.shape[0]

    @property
    def last_frame(self) -> Tensor:
        return self.frames[:, -1]

    @ordinary_tensors
    def push_frame(self, frame: Tensor) -> None:
        """Append the current frame; rows that are new or restarting get their windows refilled with it."""
        restart = ~self.started | self.restart_pending
        self.frames = torch.cat([self.frames[:, 1:], frame[:, None]], dim=1)
        self.frames[restart] = frame[restart, None]
        self.actions[restart] = 0.0
        self.plan_pos[restart] = self.plan.shape[1]
        self.attempt_planned[restart] = False
        self.started[:] = True
        self.restart_pending[:] = False

    @ordinary_tensors
    def restart(self, rows: Tensor) -> None:
        """Restart `rows` (bool, (B,)) at their next frame, as after a failed attempt."""
        self.restart_pending |= rows

    def needs_plan(self) -> Tensor:
        return self.plan_pos >= self.plan.shape[1]

    def state_condition(self, rows: Tensor) -> Tensor:
        return self.frames[rows, self.history :].flatten(start_dim=1)

    def history_condition(self, rows: Tensor) -> Tensor:
        frames = self.frames[rows, : self.history].flatten(start_dim=1)
        actions = self.actions[rows, : self.history].flatten(start_dim=1)
        return torch.cat([frames, actions], dim=-1)

    @ordinary_tensors
    def set_plan(self, rows: Tensor, chunk: Tensor, start: int) -> None:
        """Store a freshly sampled chunk (R, horizon, A) for `rows`; the attempt's first chunk is kept
        apart."""
        self.plan[rows] = chunk[:, start : start + self.plan.shape[1]]
        self.plan_pos[rows] = 0
        index = rows.nonzero().flatten()
        fresh = ~self.attempt_planned[index]
        self.attempt_chunk[index[fresh]] = chunk[fresh]
        self.latest_chunk[index] = chunk
        self.attempt_planned[index] = True

    @ordinary_tensors
    def pop_action(self) -> Tensor:
        action = self.plan[torch.arange(self.batch_size, device=self.plan.device), self.plan_pos]
        self.plan_pos += 1
        if self.actions.shape[1]:
            self.actions = torch.cat([self.actions[:, 1:], action[:, None]], dim=1)
        return action


class Rollout:
    """One rollout of a batch of rows: their windows and plans (`memory`), their failures (`failures`) and,
    with `row_noise_streams`, one noise stream per row (`samplers.row_generators`)."""

    def __init__(self, config: CCDPConfig, batch_size: int, device: torch.device, index: int):
        self.config = config
        self.memory = RolloutMemory(config, batch_size, device)
        self.failures = FailureBuffer(batch_size, config.failure_feature_dim, MAX_FAILURES, device)
        self.streams = row_generators(index, batch_size) if config.row_noise_streams else None

    @classmethod
    def after(
        cls, last: "Rollout | None", config: CCDPConfig, batch_size: int, device: torch.device, index: int
    ):
        """A new rollout `index` where the batch size changed since `last` (or none was running), warning of
        the failures it forgets."""
        if last is not None and bool((last.failures.count > 0).any()):
            logger.warning(
                "The batch went from %d to %d rows without reset(): the %d remembered failure(s) "
                "are dropped, as rows cannot be matched. Call policy.reset() between rollouts.",
                last.memory.batch_size,
                batch_size,
                int(last.failures.count.sum()),
            )
        return cls(config, batch_size, device, index)

    def record_failures(
        self, failed: Tensor, feature: FailureFeature, outcomes: OutcomeIndex, z: Tensor | None = None
    ) -> None:
        """Remember z_f for the failed rows (`failed` (B,) bool; `z` (len(rows), z_dim) as reported, or the
        feature of the attempt) and restart them at their next observation."""
        memory, rows = self.memory, failed
        if z is None:
            unplanned = failed & ~memory.attempt_planned
            if not feature.reads_failure_frame and unplanned.any():
                logger.warning(
                    "Row(s) %s failed before planning any chunk: no chunk to remember.",
                    unplanned.nonzero().flatten().tolist(),
                )
                rows = failed & memory.attempt_planned
            z = feature.of_failure(memory.last_frame, memory.attempt_chunk, memory.latest_chunk, outcomes)
        else:
            z_full = torch.zeros(memory.batch_size, self.config.failure_feature_dim, device=z.device)
            z_full[rows] = z.reshape(-1, self.config.failure_feature_dim).to(z_full.dtype)
            z = z_full
        self.failures.add(rows, z)
        memory.restart(failed)

    def plan_rows(self, rows: Tensor, noise: Tensor | None) -> PlanRows:
        """What a sampler needs of the selected rows (`rows` (B,) bool): conditions, failures, the caller's
        noise and the rows' streams."""
        z, z_mask = self.failures.padded(rows)
        streams = (
            None if self.streams is None else [self.streams[i] for i in rows.nonzero().flatten().tolist()]
        )
        conditions = self.memory.state_condition(rows), self.memory.history_condition(rows)
        return PlanRows(*conditions, z, z_mask, None if noise is None else noise[rows], streams)
