"""Common random numbers (`row_noise_streams`): DP, DP* and CCDP draw the same noise for the same episode,
whatever noise the other rows or earlier rollouts consumed, and a row without a failure plans as DP does."""

import pytest
import torch

from lerobot_ccdp.policy.samplers import row_generators

from fixtures.policy_factory import make_policy

ROWS = 3


def rollouts(mode: str, streams: bool) -> dict[str, torch.Tensor]:
    """Plans of two rollouts of a fresh policy (seed 7): the first plan, the plan after row 0 failed (DP*'s
    candidates consume extra noise there) and the next rollout's first plan."""
    torch.manual_seed(7)
    # every candidate repeats the failure: DP* draws all its rounds
    policy = make_policy(recovery_mode=mode, row_noise_streams=streams, dp_star_candidates=4, delta_z=1e9)
    policy.model.recovery_trained.fill_(True)
    obs = {"observation.state": torch.zeros(ROWS, 2)}
    with torch.inference_mode():
        first = policy.predict_action_chunk(obs)
        policy.report_failure([0])
        after = policy.predict_action_chunk(obs)
        policy.reset()
        second = policy.predict_action_chunk(obs)
    return {"first": first, "after": after, "second": second}


def test_every_method_draws_the_same_noise_for_the_same_episode():
    plans = {mode: rollouts(mode, streams=True) for mode in ("dp", "dp_star", "ccdp")}
    dp = plans["dp"]
    assert not torch.allclose(dp["first"][0], dp["first"][1])  # rows have streams of their own
    assert not torch.allclose(dp["first"], dp["second"])  # and each rollout new ones
    for mode in ("dp_star", "ccdp"):
        for plan in ("first", "second"):
            torch.testing.assert_close(plans[mode][plan], dp[plan], atol=1e-5, rtol=0, msg=f"{mode} {plan}")
        # Rows 1 and 2 had no failure: they plan as DP does while row 0 recovers beside them.
        torch.testing.assert_close(plans[mode]["after"][1:], dp["after"][1:], atol=1e-5, rtol=0, msg=mode)
        assert not torch.allclose(plans[mode]["after"][0], dp["after"][0], atol=1e-3)


def test_without_row_streams_the_extra_draws_of_dp_star_shift_the_next_rollout():
    """LeRobot's behaviour, the default: one global generator, so DP*'s candidates change DP*'s later
    plans."""
    dp, dp_star = rollouts("dp", streams=False), rollouts("dp_star", streams=False)
    torch.testing.assert_close(dp_star["first"], dp["first"])
    assert not torch.allclose(dp_star["second"], dp["second"], atol=1e-3)


@pytest.mark.parametrize("seed", [0, 2000])
def test_row_streams_follow_torch_seed_rollout_and_row(seed):
    def first_draws(torch_seed: int, rollout: int) -> list[float]:
        torch.manual_seed(torch_seed)
        return [torch.randn(1, generator=g).item() for g in row_generators(rollout, 2)]

    assert first_draws(seed, 0) == first_draws(seed, 0)
    assert len({*first_draws(seed, 0), *first_draws(seed, 1), *first_draws(seed + 1, 0)}) == 6


def test_dp_star_with_row_streams_plans_the_same_whatever_else_drew_from_torch():
    """Every DP* candidate draws from its row's stream: a second run whose global generator was advanced in
    between (other code drawing noise) plans the same after a failure (issue 114: it did not)."""

    def after_failure(advance: int) -> torch.Tensor:
        torch.manual_seed(7)
        policy = make_policy(
            recovery_mode="dp_star", row_noise_streams=True, dp_star_candidates=4, delta_z=1e9
        )
        policy.model.recovery_trained.fill_(True)
        obs = {"observation.state": torch.zeros(ROWS, 2)}
        with torch.inference_mode():
            policy.predict_action_chunk(obs)
            policy.report_failure([0])
            torch.randn(advance)  # another user of torch's global generator
            return policy.predict_action_chunk(obs)

    torch.testing.assert_close(after_failure(0), after_failure(1000), atol=0, rtol=0)
