"""DP* on a trained policy: after a failure, candidates whose failure feature repeats it are rejected.

DP* rejects by the failure feature (here the primitive of the nearest demonstrated chunk); the test reads each
sampled chunk's goal from where it ends instead, so a labeller that mislabels chunks cannot pass it.
"""

import pytest
import torch
from lerobot.policies.factory import make_pre_post_processors

from lerobot_ccdp.benchmark.reaching2d import chunks_after_failures, shares_per_goal
from lerobot_ccdp.policy.dp_star import nearest_failure_distance, reject_repeats
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

ROWS = 48


def goal_shares(policy, pre, post, failed: list[int]) -> torch.Tensor:
    """Share of sampled chunks per goal, by the goal each chunk's end position heads to."""
    _, goals = chunks_after_failures(policy, pre, post, failed, ROWS)
    return shares_per_goal(goals)


# On a policy trained 1000 steps (`skilled_checkpoint`); the scripted draws below stay in the default suite.
@pytest.mark.slow
def test_dp_star_rejects_the_failed_option_that_dp_repeats(skilled_checkpoint):
    policy = CCDPPolicy.from_pretrained(skilled_checkpoint).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(skilled_checkpoint))
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


class ScriptedDraws:
    """Candidates whose value is (round, index) and whose distances follow a script, one entry per round."""

    def __init__(self, distances: list[torch.Tensor]):
        self.distances, self.calls = distances, []

    def __call__(self, pending: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        k = len(self.calls)
        self.calls.append(pending.tolist())
        distance = self.distances[k][pending]
        m = distance.shape[1]
        value = torch.stack([torch.full((m,), float(k)), torch.arange(m, dtype=torch.float32)], dim=-1)
        return value[None, :, None].expand(len(pending), m, 1, 2), distance


def test_dp_star_keeps_the_first_accepted_candidate_and_redraws_only_rows_all_rejected():
    draws = ScriptedDraws(
        [
            torch.tensor([[0.0, 0.0, 0.7, 0.9], [0.01, 0.05, 0.02, 0.0]]),  # row 1: all within delta_z
            torch.tensor([[9.0, 9.0, 9.0, 9.0], [0.0, 0.0, 0.0, 0.6]]),
        ]
    )
    chunks = reject_repeats(draws, rows=2, rounds=3, delta_z=0.5, device=torch.device("cpu"))
    assert draws.calls == [[0, 1], [1]]  # row 0 was served in round 0; nothing pending after round 1
    assert chunks[0, 0].tolist() == [0.0, 2.0]  # round 0, first accepted candidate
    assert chunks[1, 0].tolist() == [1.0, 3.0]  # round 1, its only accepted candidate


def test_dp_star_falls_back_to_the_farthest_candidate_over_all_rounds():
    draws = ScriptedDraws([torch.tensor([[0.01, 0.3, 0.02]]), torch.tensor([[0.2, 0.1, 0.0]])])
    chunks = reject_repeats(draws, rows=1, rounds=2, delta_z=0.5, device=torch.device("cpu"))
    assert chunks[0, 0].tolist() == [0.0, 1.0]  # 0.3 in round 0 beats round 1's best, 0.2
    # one-hot z: every candidate repeats the failure, distances tie
    one_round = ScriptedDraws([torch.zeros(1, 3)])
    chunks = reject_repeats(one_round, rows=1, rounds=1, delta_z=0.5, device=torch.device("cpu"))
    assert chunks[0, 0].tolist() == [0.0, 0.0]


def test_nearest_failure_distance_ignores_empty_slots_and_rows_without_failures():
    z = torch.tensor([[[1.0, 0.0], [0.0, 1.0]], [[5.0, 5.0], [0.0, 0.0]]])
    z_mask = torch.tensor([[True, True], [False, False]])
    candidates = torch.tensor([[[1.0, 0.0], [0.0, 0.0]], [[5.0, 5.0], [1.0, 1.0]]])
    distance = nearest_failure_distance(candidates, z, z_mask)
    assert distance[0].tolist() == [0.0, 1.0]
    assert torch.isinf(distance[1]).all()
