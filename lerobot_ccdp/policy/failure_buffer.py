"""Per-row memory of failure features z_1..z_N (one row per vectorised env), kept as ordinary tensors; the
rows a report names; the failure sets the failure-set heads draw for training."""

import functools
from collections.abc import Callable
from typing import TypeVar

import torch
from torch import Tensor

T = TypeVar("T", bound=Callable)


def ordinary_tensors(method: T) -> T:
    """Run `method` outside inference mode and without autograd.

    LeRobot's loops call select_action under torch.inference_mode(), while a robot's failure detector calls
    report_failure outside it; PyTorch refuses in-place updates of inference tensors outside inference mode.
    State created and updated here stays ordinary, so every mode can read and update it.
    """

    @functools.wraps(method)
    def wrapper(*args, **kwargs):
        with torch.inference_mode(False), torch.no_grad():
            return method(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


class FailureBuffer:
    """Remembers up to `cap` failure features per batch row; beyond the cap the oldest is forgotten.

    Rows are independent: a failure in row i never shows up in another row, and clearing one row (a new
    episode in that env) leaves the others as they are. Updates work in any grad or inference mode.
    """

    @ordinary_tensors
    def __init__(self, batch_size: int, feature_dim: int, cap: int, device: torch.device | str = "cpu"):
        self.cap = cap
        self.z = torch.zeros(batch_size, cap, feature_dim, device=device)
        self.count = torch.zeros(batch_size, dtype=torch.long, device=device)

    @property
    def batch_size(self) -> int:
        return self.z.shape[0]

    @ordinary_tensors
    def add(self, rows: Tensor, z: Tensor) -> None:
        """Append z[i] to row i for every i where `rows` (bool, (B,)) is set; z is (B, feature_dim)."""
        for i in torch.nonzero(rows).flatten().tolist():
            if self.count[i] == self.cap:
                self.z[i] = torch.roll(self.z[i], shifts=-1, dims=0)
                self.count[i] -= 1
            self.z[i, self.count[i]] = z[i]
            self.count[i] += 1

    @ordinary_tensors
    def clear(self, rows: Tensor | None = None) -> None:
        """Forget the failures of `rows` (bool, (B,)), or of every row."""
        rows = torch.ones_like(self.count, dtype=torch.bool) if rows is None else rows
        self.z[rows] = 0.0
        self.count[rows] = 0

    def padded(self, rows: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """(z, mask) for the selected rows, trimmed to the largest failure count among them.

        z is (R, N, feature_dim) and mask (R, N) is True where a slot holds a failure.
        """
        z, count = (self.z, self.count) if rows is None else (self.z[rows], self.count[rows])
        n = int(count.max()) if count.numel() else 0
        mask = torch.arange(n, device=count.device)[None, :] < count[:, None]
        return z[:, :n], mask


def distinct_failures(z: Tensor, z_mask: Tensor, delta_z: float) -> Tensor:
    """(R, N) mask of the failures that are not a repeat of an earlier one in their row: within `delta_z`
    (squared distance, as the classifier's labels and DP*'s rejection measure it) of an earlier failure is the
    same option."""
    close = ((z[:, :, None] - z[:, None]) ** 2).sum(dim=-1) <= delta_z  # (R, N, N): failure i near failure j
    earlier = torch.ones(z.shape[1], z.shape[1], dtype=torch.bool, device=z.device).tril(diagonal=-1)
    return z_mask & ~(close & earlier & z_mask[:, None]).any(dim=-1)


def draw_failure_sets(z: Tensor, size: int, delta_z: float) -> tuple[Tensor, Tensor, Tensor]:
    """Training failure sets for the rows of a batch with outcomes z (B, z_dim): each row gets 1..`size`
    failures drawn from the other rows (so its set does not depend on its own chunk). Returns the sets
    (B, size, z_dim), their masks (B, size) and whether each row's own z lies within `delta_z` (squared
    distance) of a failure in its set (B,): a repeat."""
    b = z.shape[0]
    others = (torch.arange(b, device=z.device)[:, None] + torch.randint(1, b, (b, size), device=z.device)) % b
    z_set = z[others]
    z_mask = torch.arange(size, device=z.device)[None] < torch.randint(1, size + 1, (b, 1), device=z.device)
    return z_set, z_mask, in_failure_set(z[:, None], z_set, z_mask, delta_z)[:, 0]


def draw_state_failure_sets(
    z: Tensor, siblings: Tensor, count: Tensor, size: int, delta_z: float, share: float
) -> tuple[Tensor, Tensor, Tensor]:
    """`draw_failure_sets`, except that a `share` of the rows with sampled siblings (`siblings` (B, K,
    z_dim), the first `count` (B,) real, the row's own outcome among them) draw their failures from those: the
    outcomes the base reaches from the row's own state, as the failures met at that state are. Drawn from the
    other rows, a set rarely holds what the base does at the row's state, so the strata where it holds most of
    it (the hard recoveries: at the start of a task, after the base's one or two usual options failed) are
    barely trained. The siblings are the base's independent draws at the state, so F stays independent of the
    row's own chunk apart from picking the row's own entry, which puts its outcome in F and drops the row: the
    kept rows' target given (s, F) is still p_s outside F."""
    z_set, z_mask, _ = draw_failure_sets(z, size, delta_z)
    b, k = siblings.shape[:2]
    at_state = (count >= 2) & (torch.rand(b, device=z.device) < share)
    picks = (torch.rand(b, size, device=z.device) * count.clamp_min(1)[:, None]).long().clamp_max(k - 1)
    from_siblings = siblings.gather(1, picks[..., None].expand(-1, -1, siblings.shape[-1]))
    z_set = torch.where(at_state[:, None, None], from_siblings.to(z_set.dtype), z_set)
    return z_set, z_mask, in_failure_set(z[:, None], z_set, z_mask, delta_z)[:, 0]


def in_failure_set(z: Tensor, z_set: Tensor, z_mask: Tensor, delta_z: float) -> Tensor:
    """(R, M): whether each of the outcomes z (R, M, z_dim) lies within `delta_z` (squared distance) of a
    failure of its row's set (z_set (R, N, z_dim), mask (R, N)): a repeat, as DP*'s rejection counts one."""
    close = ((z[:, :, None] - z_set[:, None]) ** 2).sum(dim=-1) <= delta_z  # (R, M, N)
    return (close & z_mask[:, None]).any(dim=-1)


def stratum_weights(z_set: Tensor, z_mask: Tensor, siblings: Tensor, count: Tensor, delta_z: float) -> Tensor:
    """1 / (1 - p_s(F)) per row (R,): p_s(F) is the share of the base's chunks sampled at the row's state
    (`siblings` (R, K, z_dim), the first `count` (R,) of them real, the row's own among them) whose outcome
    lies in the row's failure set F. The set denoiser keeps a row drawn from p_s with F ~ q when its outcome
    is outside F, so a stratum (s, F) weighs q(F) (1 - p_s(F)) in its loss: the states where F holds most of
    the base's mass, where recovery matters most, are the ones it sees least. Weighting each kept row by
    1 / (1 - p_s(F)) gives every stratum q(F) and leaves each stratum's target (p_s outside F) as it is. A
    row kept has its own outcome outside F, so 1 - p_s(F) >= 1 / count; a row with no siblings (a
    demonstrated chunk) weighs 1."""
    real = torch.arange(siblings.shape[1], device=count.device)[None] < count[:, None]
    in_f = (in_failure_set(siblings, z_set, z_mask, delta_z) & real).sum(dim=1)
    p = in_f / count.clamp_min(1)
    return 1.0 / (1.0 - p).clamp_min(1.0 / siblings.shape[1])


# What `report_failure(rows=...)` takes.
ROW_FORMS = (
    "None (every row), a row index (int), a list or tensor of row indices, or a bool mask with one entry "
    "per row"
)


def row_index(rows: object) -> Tensor | None:
    """`report_failure`'s rows as a tensor of row indices or a bool mask (None: every row), refusing any
    other type before anything is recorded."""
    if rows is None:
        return None
    refused = TypeError(
        f"report_failure(rows={rows!r}) got a {type(rows).__name__}; rows takes {ROW_FORMS}. For every "
        "row, leave rows out."
    )
    if isinstance(rows, (str, bytes, bool, float)):
        raise refused
    try:
        index = torch.as_tensor(rows)
    except (TypeError, ValueError, RuntimeError):
        raise refused from None
    if index.numel() == 0:  # an empty list of rows: nothing failed
        return index.long()
    if index.ndim > 1 or (index.dtype != torch.bool and (index.is_floating_point() or index.is_complex())):
        raise refused
    return index


def failed_rows(index: Tensor | None, rows: object, batch_size: int, device: torch.device) -> Tensor:
    """Bool mask (B,) of the failed rows (`index` from `row_index(rows)`), refusing rows outside the batch the
    policy is acting on."""
    b = batch_size
    mask = torch.zeros(b, dtype=torch.bool, device=device)
    if index is None:
        return ~mask
    index = index.to(mask.device)
    # -1 would name the last row: almost surely a bug in the loop
    out_of_range = index.dtype != torch.bool and bool(((index < 0) | (index >= b)).any())
    fits = index.shape == (b,) if index.dtype == torch.bool else not out_of_range
    if not fits:
        raise ValueError(
            f"report_failure(rows={rows!r}): the policy acts on {b} row(s), indices 0..{b - 1} (or a "
            "bool mask of that length). Pass the failed rows' indices, or None for every row."
        )
    mask[index] = True
    return mask
