"""Eq. (5) pair filter and pair picking: property tests on random pairs against a brute-force reading of the
rule."""

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lerobot_ccdp.recovery.recovery_pairs import pick_pairs, recovery_pair_mask

sizes = st.integers(min_value=1, max_value=9)
thresholds = st.floats(min_value=0.0, max_value=4.0, allow_nan=False)


def random_pairs(seed: int, i: int, j: int, dz: int, dx: int) -> tuple[torch.Tensor, ...]:
    g = torch.Generator().manual_seed(seed)
    # Rounded values make exact ties with the thresholds likely, so the strict inequalities are exercised.
    r = lambda *shape: (torch.randn(*shape, generator=g) * 2).round() / 2  # noqa: E731
    return r(i, dz), r(i, dx), r(j, dz), r(j, dx)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 10**6), sizes, sizes, st.integers(1, 5), st.integers(1, 5), thresholds, thresholds)
def test_mask_is_eq5_pair_by_pair(seed, i, j, dz, dx, delta_z, delta_x):
    z_fail, x_fail, z, x = random_pairs(seed, i, j, dz, dx)
    mask = recovery_pair_mask(z_fail, x_fail, z, x, delta_z, delta_x)
    assert mask.shape == (i, j)
    for a in range(i):
        for b in range(j):
            different = float(((z[b] - z_fail[a]) ** 2).sum()) > delta_z
            nearby = float(((x[b] - x_fail[a]) ** 2).sum()) < delta_x
            assert bool(mask[a, b]) == (different and nearby), (a, b)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 10**6), sizes, st.integers(1, 4), thresholds, thresholds, thresholds)
def test_mask_properties(seed, n, d, delta_z, delta_x, extra):
    z, x, _, _ = random_pairs(seed, n, n, d, d)
    mask = recovery_pair_mask(z, x, z, x, delta_z, delta_x)
    assert not mask.diagonal().any(), "a chunk never recovers from itself (its z is identical)"
    assert torch.equal(mask, mask.T), "the rule is symmetric when failures and candidates are one set"
    # A stricter delta_z or a tighter delta_x only removes pairs.
    assert not (recovery_pair_mask(z, x, z, x, delta_z + extra, delta_x) & ~mask).any()
    assert not (recovery_pair_mask(z, x, z, x, delta_z, max(delta_x - extra, 0.0)) & ~mask).any()


def test_batched_groups_match_one_group_at_a_time():
    g = torch.Generator().manual_seed(0)
    z, x = torch.randn(3, 6, 2, generator=g), torch.randn(3, 6, 4, generator=g)
    batched = recovery_pair_mask(z, x, z, x, 1.0, 4.0)
    for b in range(3):
        assert torch.equal(batched[b], recovery_pair_mask(z[b], x[b], z[b], x[b], 1.0, 4.0))


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 10**6), st.integers(1, 4), st.integers(1, 7), st.integers(1, 60))
def test_pick_pairs_keeps_only_valid_pairs_up_to_the_limit(seed, groups, k, limit):
    g = torch.Generator().manual_seed(seed)
    mask = torch.rand(groups, k, k, generator=g) < 0.4
    group, i, j = pick_pairs(mask, limit, g)
    assert mask[group, i, j].all()
    picked = torch.bincount(group, minlength=groups)
    assert torch.equal(picked, mask.flatten(start_dim=1).sum(dim=1).clamp(max=limit))
    assert len(set(zip(group.tolist(), i.tolist(), j.tolist(), strict=True))) == len(group), "no pair twice"


def test_pick_pairs_is_uniform_over_valid_pairs():
    mask = torch.zeros(1, 4, 4, dtype=torch.bool)
    mask[0, 0, 1] = mask[0, 2, 3] = mask[0, 3, 0] = True
    g = torch.Generator().manual_seed(0)
    counts = torch.zeros(4, 4)
    for _ in range(3000):
        _, i, j = pick_pairs(mask, 1, g)
        counts[i, j] += 1
    shares = counts[mask[0]] / 3000
    assert ((shares - 1 / 3).abs() < 0.04).all(), shares
