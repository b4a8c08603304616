"""DP* on a trained policy: after a failure, candidates whose failure feature repeats it are rejected."""

import torch
from lerobot.policies.factory import make_pre_post_processors

from lerobot_ccdp.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.reaching2d import chunks_after_failures, shares_per_goal

ROWS = 48


def goal_shares(policy, pre, failed_goal: int | None) -> torch.Tensor:
    """Share of sampled chunks per goal (their nearest demonstrated chunk's primitive)."""
    _, goals = chunks_after_failures(policy, pre, [] if failed_goal is None else [failed_goal], ROWS)
    return shares_per_goal(goals)


def test_dp_star_rejects_the_failed_option_that_dp_repeats(checkpoint):
    policy = CCDPPolicy.from_pretrained(checkpoint).eval()
    pre, _ = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    policy.config.recovery_mode = "dp"
    dp = goal_shares(policy, pre, failed_goal=0)
    policy.config.recovery_mode = "dp_star"
    policy.config.delta_z = 0.5  # one-hot z: a different primitive is at squared distance 2
    dp_star = goal_shares(policy, pre, failed_goal=0)
    assert dp[0] > 0.2, f"the base policy should prefer goal 0 often, got shares {dp.tolist()}"
    assert dp_star[0] == 0.0, f"DP* repeated the failed goal: {dp_star.tolist()}"
    assert abs(float(dp_star[1:].sum()) - 1.0) < 1e-6
