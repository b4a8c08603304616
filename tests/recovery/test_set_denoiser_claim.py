"""The method that carries the name, end to end in the default suite (issue 50): on a 2-D family member,
demonstrations -> base -> lerobot-ccdp-synthesize (the failure-set denoiser's rows) -> failure-set denoiser ->
one sample per plan after one and after two failures.

The reduced form of `benchmarks/bench_preferences.py --set-denoiser`: the base and the head train in memory
(`in_memory_training.py`, lerobot-train's step) for fewer steps, on fewer synthesised rows; the rows come from
the real `lerobot-ccdp-synthesize`. Member 101 is a development member without labels (`final_state` z); the
set denoiser's test members are 12-23. `pytest -s` prints the scores.
"""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from lerobot.configs.policies import PreTrainedConfig

from lerobot_ccdp.benchmark.reaching2d import ReachingTask
from lerobot_ccdp.benchmark.reaching_preferences import Method, measure
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

from fixtures.in_memory_training import train_stage

MEMBER = 101
EPISODES = 100
BASE_STEPS = 300
HEAD_STEPS = 600  # bench_preferences.py: 1000 and 3000
# bench_preferences.SET_RECIPE with a quarter of the states: half at option starts, half along the demos.
RECIPE = {"n_states": 128, "chunks_per_state": 16, "sigma": 0.02, "w_s": 1.0, "demo_frames": 1024}
ROWS = 512
# Measured on these checkpoints (2026-11-29; 1500 head steps gave 0.021 and 0.201): CCDP 0.025 after one
# failure (DP 0.193) and 0.283 after two (DP 0.547: the two failed goals hold 0.78 of the demonstrations).
# Short training leaves more than the benchmark's 3000 steps (0.001 and 0.028 on this member), so the bounds
# are loose and relative to DP; the preference errors (0.174 and 0.134) are printed, not asserted.
AFTER_ONE, AFTER_TWO = 0.05, 0.35
FRACTION_OF_DP = {"1": 1 / 5, "2": 0.6}  # CCDP's failed share below this fraction of DP's
SYNTHESIZE = Path(sys.executable).parent / "lerobot-ccdp-synthesize"


@pytest.fixture(scope="module")
def measured(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("set_denoiser_claim")
    task = ReachingTask.family_member(MEMBER)
    repo, data = f"local/reaching_family_{MEMBER}", tmp / "data"
    task.record(data, repo, EPISODES, MEMBER)
    config = CCDPConfig(
        device="cpu", failure_feature="final_state", recovery_head="set_denoiser", history_length=0
    )
    base = train_stage(config, repo, data, tmp / "base", BASE_STEPS, 64)
    recipe = tmp / "recipe.yaml"
    recipe.write_text(yaml.safe_dump({"recovery": {"failure_feature": "final_state", **RECIPE}}))
    subprocess.run(
        [
            str(SYNTHESIZE),
            f"--config_path={recipe}",
            f"--dataset.repo_id={repo}",
            f"--dataset.root={data}",
            f"--policy.path={base}",
            "--output.repo_id=local/set_rows",
            f"--output.root={tmp / 'rows'}",
        ],
        check=True,
        capture_output=True,
    )
    head_config = PreTrainedConfig.from_pretrained(base)
    head_config.pretrained_path, head_config.training_stage = str(base), "recovery"
    head = train_stage(head_config, "local/set_rows", tmp / "rows", tmp / "head", HEAD_STEPS, 64)
    methods = {"DP": Method("dp", {}), "CCDP": Method("ccdp", {"w_z": 1.0})}
    return measure(task, head, methods, ROWS)["methods"]


def test_one_sample_per_plan_draws_the_failed_goals_far_less_than_dp(measured):
    scores = {
        (method, count): (round(m["failed_share"], 3), round(m["preference_error"], 3))
        for method in ("DP", "CCDP")
        for count, m in measured[method].items()
    }
    print(f"(failed share, preference error) per (method, failures): {scores}")
    for count, bound in (("1", AFTER_ONE), ("2", AFTER_TWO)):
        dp, ccdp = measured["DP"][count]["failed_share"], measured["CCDP"][count]["failed_share"]
        assert dp > 0.15, scores  # without memory the base keeps drawing the failed goals
        assert ccdp <= bound and ccdp < FRACTION_OF_DP[count] * dp, scores
