"""Equation (4) against eq. (2): the composed noise estimate is that of the product of densities.

Each term's noise estimate is computed from an analytic Gaussian mixture at the step's noise level
(eps = -sigma * grad log p_sigma, by autograd), and the expected composed estimate from the log of eq. (2)'s
product, p_a (p_s/p_a)^w_s (p_h/p_a)^w_h prod_i (p_z(z_i)/p_ref)^w_z, not from eq. (4)'s linear formula.
"""

import math

import pytest
import torch

from lerobot_ccdp.policy.composition import CompositionWeights, compose_eps

# noise level of the step: high enough that every mode has weight at x (the mixture weights matter)
SIGMA = 1.0
SHAPE = (4, 2)  # one action chunk: horizon x action_dim


def mixture(weights: list[float], means: torch.Tensor, spread: float = 0.1):
    """log p_sigma(x) of a Gaussian mixture diffused to noise level SIGMA, for x of shape (..., *SHAPE)."""
    variance = spread**2 + SIGMA**2
    log_w = torch.log(torch.tensor(weights, dtype=torch.float64) / sum(weights))
    means = means.to(torch.float64)

    def log_p(x: torch.Tensor) -> torch.Tensor:
        squared = ((x.unsqueeze(-3) - means) ** 2).sum(dim=(-1, -2))  # (..., K)
        dim = math.prod(SHAPE)
        return torch.logsumexp(log_w - squared / (2 * variance), dim=-1) - dim / 2 * math.log(
            2 * math.pi * variance
        )

    return log_p


def eps_of(log_p, x: torch.Tensor) -> torch.Tensor:
    """eps = -sigma * grad_x log p_sigma(x): the noise estimate an exact denoiser of p would give."""
    x = x.detach().requires_grad_(True)
    (grad,) = torch.autograd.grad(log_p(x).sum(), x)
    return -SIGMA * grad


MODES = torch.randn(4, *SHAPE, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 0.5
PREFERENCE = [0.4, 0.3, 0.2, 0.1]
P_A = mixture(PREFERENCE, MODES)  # what the demonstrations do anywhere
P_S = mixture([0.1, 0.5, 0.3, 0.1], MODES)  # ... in this state
P_H = mixture([0.25, 0.25, 0.25, 0.25], MODES)  # ... after this history


def without(option: int, weights: list[float] = PREFERENCE) -> list[float]:
    return [0.0 if k == option else w for k, w in enumerate(weights)]


P_Z = [mixture([w + 1e-12 for w in without(k)], MODES) for k in range(4)]  # recovery data: option k failed
P_Z_NULL = mixture([1.0, 1.0, 1.0, 1.0], MODES)  # recovery data with z dropped


@pytest.mark.parametrize("z_reference", ["eps_a", "eps_z_null"])
@pytest.mark.parametrize("w_s,w_h,w_z", [(1.0, 0.0, 1.0), (0.7, 0.4, 0.5), (1.5, 0.0, 3.0)])
def test_composed_eps_is_the_eps_of_the_product_of_densities(z_reference, w_s, w_h, w_z):
    x = torch.randn(5, *SHAPE, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 2
    failed = [[0, 1, 2], [1], [], [3, 0], [2]]  # rows remember different failures
    n = max(len(f) for f in failed)
    mask = torch.tensor([[i < len(f) for i in range(n)] for f in failed])
    eps_z = torch.stack(
        [
            torch.stack([eps_of(P_Z[f[i] if i < len(f) else 0], x[r]) for i in range(n)])
            for r, f in enumerate(failed)
        ]
    )
    p_ref = P_A if z_reference == "eps_a" else P_Z_NULL

    def log_product(a: torch.Tensor) -> torch.Tensor:  # the log of eq. (2), row by row
        rows = []
        for r, f in enumerate(failed):
            log = P_A(a[r]) + w_s * (P_S(a[r]) - P_A(a[r])) + w_h * (P_H(a[r]) - P_A(a[r]))
            rows.append(log + sum(w_z * (P_Z[k](a[r]) - p_ref(a[r])) for k in f))
        return torch.stack(rows)

    eps = compose_eps(
        CompositionWeights(w_s, w_h, w_z, z_reference),
        eps_of(P_A, x),
        eps_of(P_S, x),
        eps_of(P_H, x),
        eps_z,
        mask,
        eps_of(P_Z_NULL, x),
    )
    torch.testing.assert_close(eps, eps_of(log_product, x))


def test_unconditional_term_may_be_skipped_only_when_its_weight_vanishes():
    x = torch.randn(4, *SHAPE, dtype=torch.float64)
    weights = CompositionWeights(1.0, 0.0, 1.0)
    assert not weights.uses_unconditional(torch.zeros(4))
    torch.testing.assert_close(compose_eps(weights, None, eps_of(P_S, x)), eps_of(P_S, x))
    # eq. (4): eps_a's weight is 1 - w_s - w_z N
    assert weights.uses_unconditional(torch.tensor([0, 1, 0, 0]))


def test_failure_terms_against_the_null_estimate_need_it_and_not_eps_a():
    x = torch.randn(3, *SHAPE, dtype=torch.float64)
    eps_z, mask = (
        torch.stack([eps_of(P_Z[0], x), eps_of(P_Z[1], x)], dim=1),
        torch.tensor([[1, 1], [1, 0], [0, 0]]).bool(),
    )
    weights = CompositionWeights(1.0, 0.0, 0.7, "eps_z_null")
    assert not weights.uses_unconditional(mask.sum(dim=1))
    with_a = compose_eps(weights, eps_of(P_A, x), eps_of(P_S, x), None, eps_z, mask, eps_of(P_Z_NULL, x))
    torch.testing.assert_close(
        compose_eps(weights, None, eps_of(P_S, x), None, eps_z, mask, eps_of(P_Z_NULL, x)), with_a
    )
    with pytest.raises(ValueError, match="eps_z_null"):
        compose_eps(weights, None, eps_of(P_S, x), None, eps_z, mask)


def test_a_weighted_term_that_was_not_evaluated_is_an_error():
    with pytest.raises(ValueError, match="eps_h"):
        compose_eps(CompositionWeights(1.0, 0.5, 0.0), torch.zeros(1, *SHAPE), torch.zeros(1, *SHAPE))


@pytest.mark.parametrize(
    "weights,failures,terms",
    [
        (CompositionWeights(1.0, 0.0, 1.0, "eps_a"), [0, 0], ["s"]),  # eps_a's coefficient 1 - w_s is 0
        (CompositionWeights(1.0, 0.0, 1.0, "eps_a"), [0, 2], ["a", "s"]),  # -2 w_z for the row with failures
        # failures measured against eps_z_null
        (CompositionWeights(1.0, 0.0, 3.0, "eps_z_null"), [4, 1], ["s"]),
        (CompositionWeights(1.0, 0.5, 1.0, "eps_z_null"), [0, 0], ["a", "s", "h"]),
        (CompositionWeights(0.0, 0.0, 0.0), [0], ["a"]),
    ],
)
def test_only_the_base_terms_eq4_weighs_are_evaluated(weights, failures, terms):
    assert weights.base_terms(torch.tensor(failures)) == terms
