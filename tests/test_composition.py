"""Equation (4) against analytic denoisers: Gaussians whose composed distribution is known."""

import pytest
import torch

from lerobot_ccdp.composition import CompositionWeights, compose_eps


def gaussian_eps(x, mean):
    """Noise estimate of N(mean, I) at unit noise level: eps = x - mean."""
    return x - mean


@pytest.mark.parametrize("w_s,w_h,w_z", [(1.0, 0.0, 1.0), (0.7, 0.4, 0.5), (1.5, 0.0, 2.0)])
def test_composed_eps_is_the_eps_of_the_weighted_mean(w_s, w_h, w_z):
    torch.manual_seed(0)
    b, n, shape = 5, 3, (16, 2)
    x = torch.randn(b, *shape)
    mu_a, mu_s, mu_h = torch.randn(3, 1, *shape)
    mu_z = torch.randn(b, n, *shape)
    mask = torch.tensor([[1, 1, 1], [1, 0, 0], [0, 0, 0], [1, 1, 0], [1, 1, 1]], dtype=torch.bool)
    weights = CompositionWeights(w_s, w_h, w_z)
    eps = compose_eps(
        weights,
        gaussian_eps(x, mu_a),
        gaussian_eps(x, mu_s),
        gaussian_eps(x, mu_h),
        gaussian_eps(x[:, None], mu_z),
        mask,
    )
    # A product of unit Gaussians raised to these powers is the Gaussian at the weighted mean (eq. 2).
    m = mask.float()[..., None, None]
    mean = mu_a + w_s * (mu_s - mu_a) + w_h * (mu_h - mu_a) + w_z * ((mu_z - mu_a[:, None]) * m).sum(1)
    torch.testing.assert_close(eps, gaussian_eps(x, mean))


def test_unconditional_term_may_be_skipped_only_when_its_weight_vanishes():
    torch.manual_seed(1)
    x, mu_s = torch.randn(4, 16, 2), torch.randn(1, 16, 2)
    weights = CompositionWeights(1.0, 0.0, 1.0)
    no_failures = torch.zeros(4)
    assert not weights.uses_unconditional(no_failures)
    torch.testing.assert_close(compose_eps(weights, None, gaussian_eps(x, mu_s)), gaussian_eps(x, mu_s))
    assert weights.uses_unconditional(torch.tensor([0, 1, 0, 0]))


def test_failure_terms_against_the_recovery_heads_null_estimate():
    """z_reference=eps_z_null: each failure moves the mean by w_z (mu_z - mu_null), and eps_a is not needed."""
    torch.manual_seed(2)
    x, mu_s, mu_null = torch.randn(3, 16, 2), torch.randn(1, 16, 2), torch.randn(3, 16, 2)
    mu_z = torch.randn(3, 2, 16, 2)
    mask = torch.tensor([[1, 1], [1, 0], [0, 0]], dtype=torch.bool)
    weights = CompositionWeights(1.0, 0.0, 0.7, "eps_z_null")
    assert not weights.uses_unconditional(mask.sum(dim=1))
    eps = compose_eps(
        weights, None, gaussian_eps(x, mu_s), None, gaussian_eps(x[:, None], mu_z), mask, gaussian_eps(x, mu_null)
    )
    mean = mu_s + 0.7 * ((mu_z - mu_null[:, None]) * mask.float()[..., None, None]).sum(1)
    torch.testing.assert_close(eps, gaussian_eps(x, mean))
    with pytest.raises(ValueError, match="eps_z_null"):
        compose_eps(weights, None, gaussian_eps(x, mu_s), None, gaussian_eps(x[:, None], mu_z), mask)


def test_a_weighted_term_that_was_not_evaluated_is_an_error():
    with pytest.raises(ValueError, match="eps_h"):
        compose_eps(CompositionWeights(1.0, 0.5, 0.0), torch.zeros(1, 16, 2), torch.zeros(1, 16, 2))
