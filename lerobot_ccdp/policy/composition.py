"""Equation (4) of the paper: the composed noise estimate of one denoising step."""

from dataclasses import dataclass, replace

import torch
from torch import Tensor

# Floor of P(a_0 outside F | a_t, s) in `log_no_repeat`: learnt per-failure probabilities may sum past 1.
MIN_OUTSIDE = 1e-6
# What the policy measures eq. (4)'s failure terms against (`CompositionWeights.z_reference`): the recovery
# head's own z-dropped estimate, which beat the paper's eps_a on the 2-D family (docs/design_choices.md).
POLICY_Z_REFERENCE = "eps_z_null"


@dataclass(frozen=True)
class CompositionWeights:
    """w_s, w_h and w_z of eq. (4); w_z is shared by every recorded failure.

    The policy composes at w_s = 1 (the base's eps_s as trained) and its config's w_h, w_z and `w_z_steps`;
    the other weights stay here so that eq. (4) reads as the paper writes it. `z_reference` names what each
    failure term is measured against: "eps_a" (the paper's eq. 4) or "eps_z_null" (the recovery head's own
    z-dropped estimate, so that the term compares two estimates learnt from the same recovery data; see
    `compose_eps`), the policy's `POLICY_Z_REFERENCE`. `w_z_steps` limits w_z to that many of the noisiest
    reverse steps (`at_step`).
    """

    w_s: float = 1.0
    w_h: float = 0.0
    w_z: float = 1.0
    z_reference: str = "eps_a"
    w_z_steps: int | None = None

    def at_step(self, index: int) -> "CompositionWeights":
        """The weights of reverse step `index` (0 is the noisiest): w_z on the first `w_z_steps` steps (None:
        every step), w_z = 1 after them: eps_{s,F} alone, in one network call.

        A sample picks its option in the noisy steps, where guidance beyond eps_{s,F} (w_z > 1) takes most of
        what eps_{s,F} lets through onto a failed option (it favours the options far from F); in the last
        steps it no longer moves a sample already on one (docs/benchmarks.md, 2-D family).
        """
        if self.w_z_steps is None or index < self.w_z_steps:
            return self
        return replace(self, w_z=1.0, w_z_steps=None)

    def uses_unconditional(self, n_failures: Tensor) -> bool:
        """Whether eps_a carries weight for any row: its coefficient is 1 - w_s - w_h - w_z * N_row, without
        the failure part when the failure terms are measured against eps_z_null instead."""
        per_failure = self.w_z if self.z_reference == "eps_a" else 0.0
        coefficient = 1.0 - self.w_s - self.w_h - per_failure * n_failures.to(torch.float32)
        return bool((coefficient.abs() > 1e-9).any())

    @property
    def measures_against_z_null(self) -> bool:
        """Whether the failure terms need eps_z_null, the recovery head's z-dropped estimate."""
        return bool(self.w_z) and self.z_reference == "eps_z_null"

    def base_terms(self, n_failures: Tensor) -> list[str]:
        """Which outputs of the base network eq. (4) needs for rows remembering `n_failures` failures (zero
        when the failures enter otherwise): "a" (eps_a), "s" (eps_s), "h" (eps_h). Zero-weight terms are not
        evaluated."""
        terms = [name for name, w in (("s", self.w_s), ("h", self.w_h)) if w]
        if self.uses_unconditional(n_failures * bool(self.w_z)) or not terms:
            terms.insert(0, "a")
        return terms

    def failure_set_coefficients(self) -> dict[str, float]:
        """The coefficient of each estimate in `compose_with_failure_set` for a row with failures: "a"
        (eps_a), "s" (eps_s), "h" (eps_h) and "sF" (eps_{s,F}). At w_s = w_z = 1, w_h = 0 only eps_{s,F}
        remains: one network call per step."""
        return {"a": 1.0 - self.w_s - self.w_h, "s": self.w_s - self.w_z, "h": self.w_h, "sF": self.w_z}

    def failure_set_base_terms(self) -> list[str]:
        """The base network's outputs `compose_with_failure_set` needs (those with a non-zero coefficient)."""
        return [name for name, c in self.failure_set_coefficients().items() if name != "sF" and abs(c) > 1e-9]

    @classmethod
    def exploration(cls, w_s: float) -> "CompositionWeights":
        """eps_bar = eps_a + w_s (eps_s - eps_a)   (eq. 7): eq. (4) without history and failures.

        Recovery synthesis samples from it; w_s <= 1 widens the distribution beyond p_s so that the
        synthesised chunks cover every demonstrated option near a state.
        """
        if not 0.0 < w_s <= 1.0:
            raise ValueError(f"eq. (7) samples with 0 < w_s <= 1; got w_s={w_s}.")
        return cls(w_s=w_s, w_h=0.0, w_z=0.0)


def compose_eps(
    weights: CompositionWeights,
    eps_a: Tensor | None,
    eps_s: Tensor | None,
    eps_h: Tensor | None = None,
    eps_z: Tensor | None = None,
    z_mask: Tensor | None = None,
    eps_z_null: Tensor | None = None,
) -> Tensor:
    """eps = eps_a + w_s (eps_s - eps_a) + w_h (eps_h - eps_a) + sum_i w_z (eps_z(z_i) - eps_a).   (eq. 4)

    Shapes: eps_a, eps_s, eps_h are (B, horizon, action_dim); eps_z is (B, N, horizon, action_dim), one slot
    per remembered failure, with `z_mask` (B, N) marking the slots that hold a failure (rows remember
    different numbers of failures). A term whose weight is zero may be passed as None; eps_a may be None
    only when its total coefficient is zero for every row (see `CompositionWeights.uses_unconditional`).

    With `weights.z_reference == "eps_z_null"` the failure terms read w_z (eps_z(z_i) - eps_z_null), where
    eps_z_null (B, horizon, action_dim) is the recovery head with z dropped: both estimates then come from
    the recovery data, so the term keeps only what z says about the action (the ratio p_z(a|z_i) / p_z(a)),
    not how the recovery data's action marginal differs from the demonstrations'.
    """
    if eps_a is None:
        # Only valid when eps_a's total coefficient is zero: its contributions below then cancel exactly.
        eps_a = torch.zeros_like(_require(eps_s if eps_s is not None else eps_h, "eps_s or eps_h"))
    eps = eps_a
    if weights.w_s:
        eps = eps + weights.w_s * (_require(eps_s, "eps_s") - eps_a)
    if weights.w_h:
        eps = eps + weights.w_h * (_require(eps_h, "eps_h") - eps_a)
    if weights.w_z and eps_z is not None:
        mask = _require(z_mask, "z_mask").to(eps_z.dtype)[..., None, None]  # (B, N, 1, 1)
        reference = eps_a if weights.z_reference == "eps_a" else _require(eps_z_null, "eps_z_null")
        eps = eps + weights.w_z * ((eps_z - reference[:, None]) * mask).sum(dim=1)
    return eps


def compose_with_failure_set(weights: CompositionWeights, estimates: dict[str, Tensor]) -> Tensor:
    """eps = eps_a + w_s (eps_s - eps_a) + w_h (eps_h - eps_a) + w_z (eps_{s,F} - eps_s)
    (eq. 4, failure-set head)

    `recovery_head="set_denoiser"`: one term for the whole failure set F, where eq. (4) sums one term per
    failure. eps_{s,F} (`heads/set_denoiser.py`) is the noise estimate of p_s restricted to the options
    outside F, so at w_z = 1 the failure term replaces eps_s by it: exact "everything but what failed" in the
    demonstrated proportions at every noise level, up to the network's error, and w_z > 1 pushes further from
    F as classifier-free guidance does. `estimates` maps "a", "s", "h", "sF" to (B, horizon, action_dim)
    tensors; those whose coefficient (`CompositionWeights.failure_set_coefficients`) is zero may be absent.
    """
    eps = None
    for name, coefficient in weights.failure_set_coefficients().items():
        if abs(coefficient) > 1e-9:
            term = coefficient * _require(estimates.get(name), f"eps_{name}")
            eps = term if eps is None else eps + term
    return eps


def recovery_conditions(z: Tensor, null_row: bool) -> tuple[Tensor, Tensor]:
    """The recovery head's z rows (R * N [+ R], z_dim) and keep flags for eq. (4)'s failure terms, fixed for a
    whole reverse diffusion: one row per failure slot (R, N, z_dim) and, with `null_row`, one z-dropped row
    per batch row for eps_z_null; all of them go through the recovery head in one call per step."""
    r, n, dim = z.shape
    z_rows, keep_z = z.reshape(r * n, dim), z.new_ones(r * n, 1)
    if null_row:
        z_rows, keep_z = torch.cat([z_rows, z.new_zeros(r, dim)]), torch.cat([keep_z, z.new_zeros(r, 1)])
    return z_rows, keep_z


def guide_away_from_failures(
    eps: Tensor, no_repeat_gradient: Tensor, alpha_bar: Tensor, w_z: float
) -> Tensor:
    """eps - w_z sqrt(1 - alpha_bar_t) grad_{a_t} log P(a_0 outside F | a_t, s)   (classifier guidance)

    `recovery_head="classifier"`: p_s(a_t | s) P(a_0 outside F | a_t, s) is the noised p_s restricted to the
    chunks that repeat no failure of the set F, at every noise level. So at w_z = 1 this is the exact noise
    estimate of "everything but what failed" in the demonstrated proportions, up to the classifier's error,
    with one term for all failures; a sum of per-failure terms (`compose_eps`) is the score of their product
    only near zero noise. eps is the base composition (eq. 4 without failure terms), `no_repeat_gradient`
    (B, horizon, A) the gradient of the log probability and `alpha_bar` the step's cumulative signal level.
    """
    return eps - w_z * (1 - alpha_bar).sqrt() * no_repeat_gradient


def log_no_repeat(logits: Tensor, distinct: Tensor) -> Tensor:
    """log P(a_0 outside F | a_t, s), the quantity whose gradient `guide_away_from_failures` follows, from the
    classifier's logits of "repeats a failure": (R, N) logits, one per failure z_i queried alone, with
    `distinct` (R, N) marking each row's distinct failures.

    A chunk heads to one option, so "repeats z_i" and "repeats z_j" are disjoint events for distinct failed
    options, and at every noise level P(a_0 outside F) = 1 - sum_i P(a_0 repeats z_i), exact wherever the
    per-failure probabilities are, however many failures F holds. (Querying the whole set F at once kept the
    base's proportions no better on the 2-D family, docs/benchmarks.md.)
    """
    inside = (torch.sigmoid(logits) * distinct).sum(dim=1)
    return (1 - inside).clamp_min(MIN_OUTSIDE).log()


def _require(term: Tensor | None, name: str) -> Tensor:
    if term is None:
        raise ValueError(f"eq. (4) gives {name} a non-zero weight but it was not evaluated.")
    return term
