"""The method that carries the name, end to end in the default suite (issue 50): on a 2-D family member,
demonstrations -> base -> lerobot-ccdp-synthesize (the failure-set denoiser's rows) -> failure-set denoiser ->
one sample per plan after one and after two failures.

The reduced form of `lerobot_ccdp.benchmark.preference_family --set-denoiser`: the base and the head train in
memory (`in_memory_training.py`, lerobot-train's step) for fewer steps, on fewer synthesised rows; the rows
come from the real `lerobot-ccdp-synthesize`. Member 101 is a development member without labels (`final_state`
z); the family's test members are listed in docs/results.md ("Every test round"). The default suite asserts
the failed goals' share; the slow test, trained longer, also the proportions among the goals left (issue 50,
item 7). `pytest -s` prints the scores.
"""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from lerobot.configs.policies import PreTrainedConfig

from lerobot_ccdp.benchmark.reaching2d import ReachingTask
from lerobot_ccdp.benchmark.reaching_preferences import Method, measure
from lerobot_ccdp.benchmark.reaching_preferences import scores as preference_scores
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

from fixtures.in_memory_training import train_stage

MEMBER = 101
EPISODES = 100
BASE_STEPS = 300
HEAD_STEPS = 600  # preference_family: 1000 and 3000
# preference_family.SET_RECIPE with a quarter of the states: half at option starts, half along the demos.
RECIPE = {"n_states": 128, "chunks_per_state": 16, "sigma": 0.02, "w_s": 1.0, "demo_frames": 1024}
ROWS = 512
# Measured on these checkpoints (2026-11-29; 1500 head steps gave 0.021 and 0.201): CCDP 0.025 after one
# failure (DP 0.193) and 0.283 after two (DP 0.547: the two failed goals hold 0.78 of the demonstrations).
# Short training leaves more than the benchmark's 3000 steps (0.001 and 0.028 on this member), so the bounds
# are loose and relative to DP. 2026-12-05, another 2-core x86_64 machine: 0.021 and 0.254 (DP 0.180, 0.555).
AFTER_ONE, AFTER_TWO = 0.05, 0.35
FRACTION_OF_DP = {"1": 1 / 5, "2": 0.6}  # CCDP's failed share below this fraction of DP's
# The proportions among the goals left, against the exact answer (the base's own shares renormalised over
# them), need a longer training than the default suite's: at 600 head steps the preference error (total
# variation) was 0.174 / 0.134 after one / two failures (2026-11-29) and 0.180 / 0.090 (2026-12-05), where
# drawing the goals left uniformly scores 0.159 after one failure. The slow test trains the base
# LONG_BASE_STEPS and the head LONG_HEAD_STEPS on preference_family.SET_RECIPE's 512 states. Measured
# (2026-12-05, 2-core x86_64): failed share 0.001 / 0.021, preference error 0.122 / 0.026, a uniform draw's
# 0.198 / 0.290. Asserted with margins 0.009 / 0.029 (failed) and 0.048 / 0.054 (error), and below the uniform
# draw's error. The benchmark's head (24000 steps on 2048 states, over half an hour a member) scores 0.023 /
# 0.005 on this member (`git show 0032ef5:docs/benchmarks.md`, "Twice the head steps"), the family's mean
# 0.048 / 0.036.
LONG_FAILED_SHARE = {"1": 0.01, "2": 0.05}
LONG_PREFERENCE_ERROR = {"1": 0.17, "2": 0.08}
LONG_BASE_STEPS, LONG_HEAD_STEPS = 1000, 6000
LONG_RECIPE = {**RECIPE, "n_states": 512, "demo_frames": 4096}
LONG_ROWS = 2048
SYNTHESIZE = Path(sys.executable).parent / "lerobot-ccdp-synthesize"


def measure_member(tmp: Path, base_steps: int, head_steps: int, recipe: dict, rows: int) -> dict:
    """Demonstrations -> base -> synthesised rows -> set denoiser, then DP's and CCDP's plans scored."""
    task = ReachingTask.family_member(MEMBER)
    repo, data = f"local/reaching_family_{MEMBER}", tmp / "data"
    task.record(data, repo, EPISODES, MEMBER)
    config = CCDPConfig(  # torch's global generator, as the claim's figures were measured
        device="cpu",
        failure_feature="final_state",
        recovery_head="set_denoiser",
        history_length=0,
        row_noise_streams=False,
    )
    base = train_stage(config, repo, data, tmp / "base", base_steps, 64)
    recipe_file = tmp / "recipe.yaml"
    recipe_file.write_text(yaml.safe_dump({"recovery": recipe}))
    subprocess.run(
        [
            str(SYNTHESIZE),
            f"--config_path={recipe_file}",
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
    head = train_stage(head_config, "local/set_rows", tmp / "rows", tmp / "head", head_steps, 64)
    methods = {"DP": Method("dp", {}), "CCDP": Method("ccdp", {"w_z": 1.0})}
    return measure(task, head, methods, rows)


@pytest.fixture(scope="module")
def measured(tmp_path_factory) -> dict:
    return measure_member(tmp_path_factory.mktemp("set_denoiser_claim"), BASE_STEPS, HEAD_STEPS, RECIPE, ROWS)


def test_one_sample_per_plan_draws_the_failed_goals_far_less_than_dp(measured):
    scores = {
        (method, count): (round(m["failed_share"], 3), round(m["preference_error"], 3))
        for method in ("DP", "CCDP")
        for count, m in measured["methods"][method].items()
    }
    print(f"(failed share, preference error) per (method, failures): {scores}")
    for count, bound in (("1", AFTER_ONE), ("2", AFTER_TWO)):
        dp = measured["methods"]["DP"][count]["failed_share"]
        ccdp = measured["methods"]["CCDP"][count]["failed_share"]
        assert dp > 0.15, scores  # without memory the base keeps drawing the failed goals
        assert ccdp <= bound and ccdp < FRACTION_OF_DP[count] * dp, scores


@pytest.mark.slow  # about 10 min on a 2-core machine
def test_one_sample_per_plan_keeps_the_base_proportions_among_the_goals_left(tmp_path):
    measured = measure_member(tmp_path, LONG_BASE_STEPS, LONG_HEAD_STEPS, LONG_RECIPE, LONG_ROWS)
    reference = np.asarray(measured["dp_shares"])
    for count, m in measured["methods"]["CCDP"].items():
        uniform = np.full(len(reference), 1.0 / (len(reference) - len(m["failed"])))
        uniform[m["failed"]] = 0.0
        _, uniform_error = preference_scores(uniform, reference, m["failed"])
        print(
            f"after {count}: {m['failed_share']:.3f} failed, preference error {m['preference_error']:.3f}, "
            f"a uniform draw's {uniform_error:.3f}"
        )
        assert m["failed_share"] <= LONG_FAILED_SHARE[count], (count, m)
        assert m["preference_error"] <= LONG_PREFERENCE_ERROR[count], (count, m)
        assert m["preference_error"] < uniform_error, (count, m, uniform_error)
