"""The recovery modes: how one plan per row is drawn from the model, given the row's recorded failures.

Each mode is a function `(model, PlanRows) -> chunks (R, horizon, A)` in `SAMPLERS`, so a new method is one
function here. All of them run the model's one reverse diffusion (`CCDPModel.denoise`):
- dp: the base policy, failures ignored;
- dp_star: the paper's baseline, the base's candidates with those that would repeat a failure rejected;
- ccdp: eq. (4) with the recovery head, one sample per plan.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from diffusers.utils.torch_utils import randn_tensor
from torch import Tensor

from lerobot_ccdp.policy.dp_star import nearest_failure_distance, reject_repeats

if TYPE_CHECKING:  # the model module imports this one
    from lerobot_ccdp.policy.modeling_ccdp import CCDPModel


@dataclass
class PlanRows:
    """The rows that need a plan: their conditions, their failures (`z` (R, N, z_dim), `z_mask` (R, N)), the
    caller's initial noise for them (or None: drawn) and one noise stream per row (`row_generators`, or
    None)."""

    state: Tensor
    history: Tensor
    z: Tensor
    z_mask: Tensor
    noise: Tensor | None = None
    streams: list[torch.Generator] | None = None

    def initial_noise(self, model: CCDPModel) -> Tensor:
        shape = (self.state.shape[0], model.config.horizon, model.config.action_dim)
        return self.noise if self.noise is not None else draw_noise(shape, self.streams, self.state.device)


def plan_dp(model: CCDPModel, rows: PlanRows) -> Tensor:
    """The base policy's plan: what was recorded as failed plays no part."""
    no_failures = rows.z[:, :0], rows.z_mask[:, :0]
    return model.denoise(
        rows.initial_noise(model), rows.state, rows.history, *no_failures, generators=rows.streams
    )


def plan_dp_star(model: CCDPModel, rows: PlanRows) -> Tensor:
    """DP*: `dp_star_candidates` base plans per round for up to `dp_star_rounds` rounds, the first whose
    outcome repeats no failure kept. Rows without failures plan as DP."""
    if not rows.z_mask.any():
        return plan_dp(model, rows)
    cfg = model.config
    return sample_without_repeats(model, rows, cfg.dp_star_candidates, cfg.dp_star_rounds)


def plan_ccdp(model: CCDPModel, rows: PlanRows) -> Tensor:
    """CCDP: one sample from eq. (4) with every recorded failure."""
    return model.denoise(
        rows.initial_noise(model), rows.state, rows.history, rows.z, rows.z_mask, generators=rows.streams
    )


SAMPLERS: dict[str, Callable[[CCDPModel, PlanRows], Tensor]] = {
    "dp": plan_dp,
    "dp_star": plan_dp_star,
    "ccdp": plan_ccdp,
}


def sample_without_repeats(model: CCDPModel, rows: PlanRows, candidates: int, rounds: int) -> Tensor:
    """One chunk per row that repeats none of its row's failures, by `dp_star.reject_repeats`: each round
    draws `candidates` chunks per pending row from the base with failures ignored (DP*), and labels them with
    the outcome of the nearest demonstrated chunk. With row streams every candidate draws from its row's
    (`candidate_streams`), so DP* is reproducible whatever else consumed torch's global generator."""
    cfg = model.config
    state, history, z, z_mask = rows.state, rows.history, rows.z, rows.z_mask
    round_index = iter(range(rounds))

    def draw(pending: Tensor) -> tuple[Tensor, Tensor]:
        r = pending.shape[0]
        generators = candidate_streams(rows.streams, pending.tolist(), candidates, next(round_index))
        noise = draw_noise((r * candidates, cfg.horizon, cfg.action_dim), generators, state.device)
        chunks = model.denoise(
            noise,
            state[pending].repeat_interleave(candidates, dim=0),
            history[pending].repeat_interleave(candidates, dim=0),
            z[pending][:, :0].repeat_interleave(candidates, dim=0),
            z_mask[pending][:, :0].repeat_interleave(candidates, dim=0),
            generators=generators,
        )
        z_candidates = model.feature.from_chunk(chunks, model.outcomes).view(r, candidates, -1)
        distance = nearest_failure_distance(z_candidates, z[pending], z_mask[pending])
        return chunks.view(r, candidates, cfg.horizon, cfg.action_dim), distance

    return reject_repeats(draw, state.shape[0], rounds, cfg.delta_z, state.device)


# ----- common random numbers: one noise stream per batch row of each rollout ------------------------------
#
# Methods compared on the same seeds (DP, DP*, CCDP) sample the same base policy until an episode's first
# failure; with torch's global generator their plans still differ from the first one, because each method
# has consumed a different amount of noise by then (DP*'s candidates, CCDP's redraws, earlier rollouts).
# Drawing each row's plans from a generator seeded from (torch's seed, the rollout's index, the row) gives
# every method the same noise for the same episode, so a paired comparison measures what happens after
# failures, not the luck before them. It also makes a row's plans independent of the other rows in the batch.


def row_generators(rollout: int, rows: int) -> list[torch.Generator]:
    """CPU generators, one per row of rollout number `rollout` since the policy was made, seeded from
    `torch.initial_seed()` (lerobot-eval's `--seed`), so two processes run with the same seed agree."""
    seeds = np.random.SeedSequence([torch.initial_seed(), rollout]).spawn(rows)
    return [
        torch.Generator().manual_seed(int(s.generate_state(1, np.uint64)[0] >> np.uint64(1))) for s in seeds
    ]


def candidate_streams(
    streams: list[torch.Generator] | None, rows: list[int], candidates: int, round_index: int
) -> list[torch.Generator] | None:
    """Generators for `candidates` draws per row of `rows` in DP*'s round `round_index`: the first round's
    first candidate from the row's own stream (the chunk a method without candidates plans), every other one
    from a generator seeded from (the row stream's seed, the round, the candidate)."""
    if streams is None:
        return None

    def child(stream: torch.Generator, candidate: int) -> torch.Generator:
        seed = np.random.SeedSequence([stream.initial_seed(), round_index, candidate]).generate_state(
            1, np.uint64
        )
        return torch.Generator().manual_seed(int(seed[0] >> np.uint64(1)))

    return [
        streams[row] if round_index == 0 and candidate == 0 else child(streams[row], candidate)
        for row in rows
        for candidate in range(candidates)
    ]


def draw_noise(
    shape: tuple[int, ...], generators: list[torch.Generator] | None, device: torch.device
) -> torch.Tensor:
    """Gaussian noise of `shape`, row i from `generators[i]`, or from torch's global generator without
    them."""
    return randn_tensor(shape, generator=generators, device=device)
