"""DP*, the paper's rejection-sampling baseline: candidate chunks from the base policy, those that would
repeat a recorded failure rejected."""

from collections.abc import Callable

import torch
from torch import Tensor


def nearest_failure_distance(z_candidates: Tensor, z: Tensor, z_mask: Tensor) -> Tensor:
    """Squared z distance (R, M) from each candidate (R, M, z_dim) to its row's nearest recorded failure
    (R, N, z_dim); infinite for a row that holds no failure (`z_mask` (R, N) marks the slots in use)."""
    distance = ((z_candidates[:, :, None] - z[:, None]) ** 2).sum(dim=-1)  # (R, M, N)
    return distance.masked_fill(~z_mask[:, None], float("inf")).min(dim=-1).values


def reject_repeats(
    draw: Callable[[Tensor], tuple[Tensor, Tensor]],
    rows: int,
    rounds: int,
    delta_z: float,
    device: torch.device,
) -> Tensor:
    """One chunk per row: the first candidate farther than `delta_z` from every failure of its row.

    `draw(pending)` returns fresh candidates (P, M, horizon, A) for the row indices `pending` (P,) and their
    distances to the nearest failure (P, M). A row whose candidates are all rejected draws again, up to
    `rounds` rounds; rejected in every round, it keeps the candidate farthest from its failures. Candidates
    are i.i.d., so the first accepted one is a uniform pick among the accepted.
    """
    pending = torch.arange(rows, device=device)
    # each row's kept chunk: distance to nearest failure
    kept = torch.full((rows,), -float("inf"), device=device)
    chunks: Tensor | None = None
    for _ in range(rounds):
        candidates, distance = draw(pending)
        accepted = distance > delta_z
        m, drawn = distance.shape[1], torch.arange(pending.shape[0], device=device)
        order = (m - torch.arange(m, device=device, dtype=distance.dtype))[None]
        pick = torch.where(accepted, order, -1.0 / (1.0 + distance)).argmax(dim=1)
        if chunks is None:
            chunks = candidates.new_empty(rows, *candidates.shape[2:])
        picked = distance[drawn, pick]
        better = picked > kept[pending]
        chunks[pending[better]] = candidates[drawn, pick][better]
        kept[pending[better]] = picked[better]
        pending = pending[~accepted.any(dim=1)]
        if pending.numel() == 0:
            break
    return chunks
