"""Recovery on two members of issue 17's seeded 2-D family: after one and after two failures, CCDP's
failure-set classifier guidance samples the failed goals a third as often as DP or less.

The reduced form of `lerobot_ccdp.benchmark.preference_family`: the same members, measurement and settings,
trained in memory (`in_memory_training.py`) instead of through lerobot-train so that CI can afford it. Member
0 carries `primitive` labels; member 1 has none and uses `final_state` z. Issue 17's targets (failed share
<= 0.03, preference error <= 0.08) are not asserted, as these short trainings leave some members and counts
above them, even under the exact classifier's guidance: the scores are printed (`pytest -s -k preferences`),
and docs/benchmarks.md has the family's figures and what was tried.
"""

from pathlib import Path

import pytest
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_ccdp.benchmark.reaching2d import ReachingTask
from lerobot_ccdp.benchmark.reaching_preferences import Method, measure
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

from fixtures.in_memory_training import train_stage

EPISODES = 100
BASE_STEPS = 300
HEAD_STEPS = 600  # preference_family: 1000 and 3000
ROWS = 512
# Issue 17 asks 0.03 on the family's mean, which one sample per plan does not meet (docs/benchmarks.md); this
# bounds each member and count, where these checkpoints measured 0.000 to 0.104 (2026-11-28, each failure
# queried alone; 0.004 to 0.023 when the whole set was queried at once, a form since removed).
FAILED_SHARE = 0.15
EXACT_FAILED_SHARE = 0.05


def member_checkpoint(seed: int, tmp: Path) -> tuple[Path, LeRobotDataset]:
    """Record member `seed`, train its base and its failure-set classifier; return the classifier's checkpoint
    and the demonstrations."""
    task = ReachingTask.family_member(seed)
    repo, data = f"local/reaching_family_{seed}", tmp / "data"
    task.record(data, repo, EPISODES, seed)
    z = (
        {"failure_feature": "primitive", "num_primitives": len(task.goals)}
        if task.labelled
        else {"failure_feature": "final_state"}
    )
    # the base as measured: its head named `unet` (its untrained weights drawn from the seeded generator
    # before training), not the set denoiser its state inputs default to
    base = train_stage(
        CCDPConfig(device="cpu", recovery_head="unet", **z), repo, data, tmp / "base", BASE_STEPS, 64
    )
    head_config = PreTrainedConfig.from_pretrained(base)
    head_config.pretrained_path = str(base)
    head_config.training_stage, head_config.recovery_head = "recovery", "classifier"
    return train_stage(head_config, repo, data, tmp / "classifier", HEAD_STEPS, 64), LeRobotDataset(
        repo, root=data
    )


@pytest.fixture(scope="module")
def measured(tmp_path_factory) -> dict[int, dict]:
    results = {}
    for seed in (0, 1):
        checkpoint, demos = member_checkpoint(seed, tmp_path_factory.mktemp(f"m{seed}"))
        methods = {
            "DP": Method("dp", {}),
            "CCDP": Method("ccdp", {"w_z": 1.0}),
            "CCDP exact": Method("ccdp", {"w_z": 1.0}, demos),
        }
        results[seed] = measure(ReachingTask.family_member(seed), checkpoint, methods, ROWS)
    return results


@pytest.mark.slow  # about 2 min; the default suite's 2-D claim is test_set_denoiser_claim.py
def test_classifier_guidance_avoids_failed_goals_where_dp_repeats_them(measured):
    scores = {
        (seed, method, count): (round(m["failed_share"], 3), round(m["preference_error"], 3))
        for seed, result in measured.items()
        for method in ("DP", "CCDP", "CCDP exact")
        for count, m in result["methods"][method].items()
    }
    report = f"(failed share, preference error) per (member, method, failures): {scores}"
    print(report)
    for seed in measured:
        for count in "12":
            dp_failed, ccdp_failed = scores[(seed, "DP", count)][0], scores[(seed, "CCDP", count)][0]
            assert dp_failed > 0.2, report  # without memory the base keeps drawing its favourite goals
            assert ccdp_failed <= min(FAILED_SHARE, dp_failed / 3), report
            # The same learnt base guided by the exact classifier of the demonstrated start chunks: the
            # guidance, the sampler and the gradient under inference mode leave almost nothing of the failed
            # goals (measured 0.000 to 0.004 on these checkpoints, 2026-11-27).
            assert scores[(seed, "CCDP exact", count)][0] <= EXACT_FAILED_SHARE, report
