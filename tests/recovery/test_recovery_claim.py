"""The method's claim end to end on the 2-D four-goal task, through the real CLIs.

Base (lerobot-train, 1000 steps) -> lerobot-ccdp-synthesize with datasets_recipes/reaching2d.yaml ->
lerobot-train --policy.training_stage=recovery. After a failure at one goal, CCDP rarely samples that goal
again while DP keeps its demonstrated share, and the least preferred goal stays the least sampled; after
failures at two goals both are avoided and the two remaining goals keep their demonstrated order (what issue 4
asks).

The recovery stage runs as the task configs do: failure terms against eps_z_null (the default) with
`--policy.w_z=3`, and a longer head training (3000 steps) than the base. At w_z = 1 or with 1500 steps the
claim did not hold on this base (measured 2026-11-23, 512 rows, seed 0, shares per goal):
- 1500 steps, w_z = 1: after goals 0 and 1 failed 0.21 / 0.22 / 0.28 / 0.28 (not avoided; eps_a 0.09 / 0.17 /
  0.32 / 0.42, goal 3 above goal 2);
- 3000 steps, w_z = 1: 0.12 / 0.19 / 0.43 / 0.26 (goal 0 above a quarter of DP's 0.42);
- 3000 steps, w_z = 3: DP 0.42 / 0.29 / 0.20 / 0.09; after goal 0 failed 0.00 / 0.31 / 0.63 / 0.06; after
  goals 0 and 1 failed 0.02 / 0.03 / 0.62 / 0.33.
Not asserted: after ONE failure goals 1 and 2 swap places (demonstrated 0.3 > 0.2). eq. (4)'s sum of noise
estimates at high noise pushes samples to the goal opposite the failed one (west, goal 2, after east failed),
and more so as w_z grows. The README's Fig. 2 paragraph ("Benchmarks") has the figures and what was tried.
"""

from pathlib import Path

import pytest
import torch
from lerobot.policies.factory import make_pre_post_processors

from lerobot_ccdp.benchmark.reaching2d import chunks_after_failures, shares_per_goal
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

from fixtures.reaching import REACHING_REPO_ID, run_cli, train_args

RECIPE = Path(__file__).parents[2] / "datasets_recipes" / "reaching2d.yaml"
ROWS = 512
RECOVERY_STEPS = 3000
W_Z = 3.0  # as configs/*/train_base.json


@pytest.fixture(scope="module")
def recovery_checkpoint(reaching_root, tmp_path_factory) -> Path:
    # Its own base, batch 64: on the shared batch-32 base two failures are avoided less (goals 0 and 1 came
    # back in 0.40 of the samples and goal 3 outnumbered goal 2).
    tmp = tmp_path_factory.mktemp("recovery")
    run_cli(*train_args(reaching_root, tmp / "base", 1000, "--save_freq=1000", batch_size=64))
    checkpoint = tmp / "base" / "checkpoints" / "last" / "pretrained_model"
    run_cli(
        "lerobot-ccdp-synthesize",
        f"--config_path={RECIPE}",
        f"--dataset.repo_id={REACHING_REPO_ID}",
        f"--dataset.root={reaching_root}",
        f"--policy.path={checkpoint}",
        "--output.repo_id=local/reaching2d_recovery",
        f"--output.root={tmp / 'data'}",
    )
    run_cli(
        "lerobot-train",
        f"--policy.path={checkpoint}",
        "--policy.training_stage=recovery",
        f"--policy.w_z={W_Z}",
        "--dataset.repo_id=local/reaching2d_recovery",
        f"--dataset.root={tmp / 'data'}",
        f"--output_dir={tmp / 'run'}",
        f"--steps={RECOVERY_STEPS}",
        "--batch_size=64",
        f"--save_freq={RECOVERY_STEPS}",
        "--policy.push_to_hub=false",
        "--num_workers=0",
        "--wandb.enable=false",
        "--log_freq=100",
        "--seed=0",
    )
    return tmp / "run" / "checkpoints" / "last" / "pretrained_model"


def goal_shares(policy: CCDPPolicy, pre, post, mode: str, failed: list[int]) -> torch.Tensor:
    """Share of freshly planned chunks per goal after `failed` goals were reported as failures in every
    row."""
    policy.config.recovery_mode = mode
    _, goals = chunks_after_failures(policy, pre, post, failed, ROWS)
    return shares_per_goal(goals)


@pytest.mark.slow
def test_ccdp_avoids_failed_goals(recovery_checkpoint):
    policy = CCDPPolicy.from_pretrained(recovery_checkpoint).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(recovery_checkpoint))
    dp = goal_shares(policy, pre, post, "dp", failed=[0])
    one = goal_shares(policy, pre, post, "ccdp", failed=[0])
    two = goal_shares(policy, pre, post, "ccdp", failed=[0, 1])
    report = f"dp {dp.tolist()}, ccdp after goal 0 failed {one.tolist()}, after goals 0 and 1 {two.tolist()}"
    print(report)  # the shares docs/benchmarks.md quotes (`pytest -s`)
    assert dp[0] > 0.3, report  # demonstrated share 0.4: DP resamples the failed goal
    assert one[0] < dp[0] / 4, report
    assert one[1:].sum() > 0.85, report
    assert one[3] < min(one[1], one[2]), report  # the least preferred goal stays the least sampled
    assert two[0] + two[1] < (dp[0] + dp[1]) / 2, report
    assert two[0] < dp[0] / 4 and two[1] < dp[1], report
    assert two[2] > two[3], report  # demonstrated 0.2 > 0.1: the remaining goals keep their order
