"""`python -m lerobot_ccdp.benchmark.policy_cost` and `camera_cost`, run in-process as a user runs them,
reduced to one timed call each: every configuration is timed against LeRobot's diffusion policy, the table is
printed and the same figures are kept as JSON with the command that made them."""

import json

import pytest
import torch

from lerobot_ccdp.benchmark import camera_cost, policy_cost, synthesis_cost

# The tools set torch's thread count; the test's own keeps the rest of the suite's.
THREADS = ["--threads", str(torch.get_num_threads())]


def test_policy_cost_times_every_recovery_mode_against_diffusion(tmp_path, capsys):
    out = tmp_path / "policy_cost.json"
    results = policy_cost.main(
        ["--no-cli", "--repeats", "1", "--warmup", "0", "--train-steps", "1", "--batch-size", "4", *THREADS]
        + ["--work", str(tmp_path / "work"), "--out", str(out)]
    )
    rows = {row["name"]: row for row in results["latency"]["rows"]}
    expected = ["diffusion", *(f"ccdp N={n}" for n in policy_cost.FAILURE_COUNTS)]
    assert list(rows)[: len(expected)] == expected
    assert {"dp_star N=4", "dp_star matched N=4", "dp N=4"} <= set(rows)
    assert rows["diffusion"]["ratio_vs_diffusion"] == 1.0
    assert results["latency"]["ratio_at_n4"] == rows["ccdp N=4"]["ratio_vs_diffusion"] > 0
    assert set(results["train_step"]["median_ms"]) == {"diffusion", "ccdp"}
    kept = json.loads(out.read_text())
    assert kept["table"] == results["table"] and "lerobot_train" not in kept  # --no-cli: no lerobot-train
    assert kept["args"]["command"].startswith("python -m lerobot_ccdp.benchmark.policy_cost --no-cli")
    assert "| planning latency (ms, median) | ccdp N=4 |" in capsys.readouterr().out


def test_camera_cost_times_both_policies_on_the_same_camera_and_a_rendered_size(tmp_path, capsys):
    out = tmp_path / "camera_cost.json"
    results = camera_cost.main(
        ["--no-cli", "--repeats", "1", "--warmup", "0", "--train-steps", "1", "--batch-size", "2", *THREADS]
        + ["--size", "48", "--sizes", "48", "--work", str(tmp_path / "work"), "--out", str(out)]
    )
    assert set(results["latency"]["median_ms"]) == {"diffusion", "ccdp N=0", "ccdp N=4"}
    assert set(results["train_step"]["median_ms"]) == {"diffusion", "ccdp H=0", "ccdp H=2"}
    assert set(results["render_sizes"]) == {48} and results["render_sizes"][48]["env_step_ms"] > 0
    assert json.loads(out.read_text())["table"] == results["table"]
    assert "| render size 48x48 |" in capsys.readouterr().out


@pytest.mark.parametrize("tool", [policy_cost, camera_cost, synthesis_cost])
def test_a_work_folder_the_tool_did_not_make_is_refused_untouched(tool, tmp_path, capsys):
    work = tmp_path / "mine"
    work.mkdir()
    (work / "keep.txt").write_text("mine")
    with pytest.raises(SystemExit, match="Refusing --work"):
        tool.main(
            ["--work", str(work), "--out", str(tmp_path / "out.json")][: 2 if tool is synthesis_cost else 4]
        )
    assert [p.name for p in work.iterdir()] == ["keep.txt"]
