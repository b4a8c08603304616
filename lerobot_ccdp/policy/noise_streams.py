"""Common random numbers: one noise stream per batch row of each rollout.

Methods compared on the same seeds (DP, DP*, CCDP) sample the same base policy until an episode's first
failure; with torch's global generator their plans still differ from the first one, because each method has
consumed a different amount of noise by then (DP*'s candidates, CCDP's redraws, earlier rollouts). Drawing
each row's plans from a generator seeded from (torch's seed, the rollout's index, the row) gives every method
the same noise for the same episode, so a paired comparison measures what happens after failures, not the luck
before them. It also makes a row's plans independent of the other rows in the batch.
"""

from __future__ import annotations

import numpy as np
import torch
from diffusers.utils.torch_utils import randn_tensor


def row_generators(rollout: int, rows: int) -> list[torch.Generator]:
    """CPU generators, one per row of rollout number `rollout` since the policy was made, seeded from
    `torch.initial_seed()` (lerobot-eval's `--seed`), so two processes run with the same seed agree."""
    seeds = np.random.SeedSequence([torch.initial_seed(), rollout]).spawn(rows)
    return [
        torch.Generator().manual_seed(int(s.generate_state(1, np.uint64)[0] >> np.uint64(1))) for s in seeds
    ]


def first_candidates(streams: list[torch.Generator] | None, candidates: int) -> list[torch.Generator] | None:
    """Generators for `candidates` draws per row: each row's first candidate from the row's stream, the others
    from torch's global generator, so the first candidate is the chunk a method without candidates plans."""
    if streams is None:
        return None
    return [g for stream in streams for g in [stream] + [torch.default_generator] * (candidates - 1)]


def draw_noise(
    shape: tuple[int, ...], generators: list[torch.Generator] | None, device: torch.device
) -> torch.Tensor:
    """Gaussian noise of `shape`, row i from `generators[i]`, or from torch's global generator without
    them."""
    return randn_tensor(shape, generator=generators, device=device)
