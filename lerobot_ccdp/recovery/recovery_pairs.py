"""Equation (5) of the paper: which (failure, action) pairs enter the recovery dataset.

An action a recovers from a failure (a_f, x_f) when it does something else and is taken in (almost) the same
state, assuming the cause of the failure is static:

    ||z(a, x) - z(a_f, x_f)||^2 > delta_z   and   ||x - x_f||^2 < delta_x            (eq. 5)
"""

import torch
from torch import Tensor


def recovery_pair_mask(
    z_fail: Tensor, x_fail: Tensor, z: Tensor, x: Tensor, delta_z: float, delta_x: float
) -> Tensor:
    """mask[..., i, j] is True when candidate j (feature z[j] at state x[j]) recovers from failure i.

    Shapes: z_fail (..., I, Dz), x_fail (..., I, Dx), z (..., J, Dz), x (..., J, Dx) -> (..., I, J). Distances
    are summed exactly in float64 (no matmul shortcut, no square root) so that the thresholds mean what they
    say.
    """
    return (squared_distances(z_fail, z) > delta_z) & (squared_distances(x_fail, x) < delta_x)


def squared_distances(a: Tensor, b: Tensor) -> Tensor:
    """||a_i - b_j||^2 for a (..., I, D) and b (..., J, D) -> (..., I, J), one dimension at a time to bound
    memory."""
    a, b = a.double(), b.double()
    out = torch.zeros(*a.shape[:-1], b.shape[-2], dtype=torch.float64)
    for d in range(a.shape[-1]):
        out += (a[..., :, None, d] - b[..., None, :, d]) ** 2
    return out


def pick_pairs(mask: Tensor, limit: int, generator: torch.Generator | None = None) -> tuple[Tensor, ...]:
    """Up to `limit` pairs per leading group, uniformly at random among the True entries of mask (..., I, J).

    Returns the index tensors (group indices..., i, j) of the kept pairs, like `mask.nonzero(as_tuple=True)`.
    """
    flat = mask.reshape(-1, mask.shape[-2] * mask.shape[-1])
    scores = torch.rand(flat.shape, generator=generator).masked_fill(~flat, -1.0)
    top = scores.topk(min(limit, flat.shape[1]), dim=1)
    group, slot = (top.values >= 0).nonzero(as_tuple=True)
    chosen = torch.zeros_like(flat)
    chosen[group, top.indices[group, slot]] = True
    return chosen.reshape(mask.shape).nonzero(as_tuple=True)
