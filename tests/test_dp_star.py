"""DP* on a trained policy: after a failure, candidates whose failure feature repeats it are rejected.

DP* rejects by the failure feature (here the primitive of the nearest demonstrated chunk); the test reads each
sampled chunk's goal from where it ends instead, so a labeller that mislabels chunks cannot pass it.
"""

import torch
from lerobot.policies.factory import make_pre_post_processors

from lerobot_ccdp.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.reaching2d import chunks_after_failures, shares_per_goal

ROWS = 48


def goal_shares(policy, pre, post, failed: list[int]) -> torch.Tensor:
    """Share of sampled chunks per goal, by the goal each chunk's end position heads to."""
    _, goals = chunks_after_failures(policy, pre, post, failed, ROWS)
    return shares_per_goal(goals)


def test_dp_star_rejects_the_failed_option_that_dp_repeats(checkpoint):
    policy = CCDPPolicy.from_pretrained(checkpoint).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    policy.config.recovery_mode = "dp"
    dp = goal_shares(policy, pre, post, failed=[0])
    policy.config.recovery_mode = "dp_star"
    policy.config.delta_z = 0.5  # one-hot z: a different primitive is at squared distance 2
    one = goal_shares(policy, pre, post, failed=[0])
    two = goal_shares(policy, pre, post, failed=[0, 1])
    report = f"dp {dp.tolist()}, dp* after goal 0 {one.tolist()}, after goals 0 and 1 {two.tolist()}"
    assert dp[0] > 0.2, report  # the base policy heads to the failed goal often (demonstrated 0.4)
    assert one[0] <= 1 / ROWS, report
    assert two[0] + two[1] <= 1 / ROWS, report
