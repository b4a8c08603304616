"""`python -m lerobot_ccdp.benchmark.synthesis_cost` in-process on the 2-D task from a skilled base: it
records the demos, synthesises the recovery set with the task's recipe, trains the recovery stage with
lerobot-train, prints the stage table, draws the paper's Fig. 2 and tabulates the goal shares per reverse
sampler."""

import pytest
import yaml


@pytest.mark.slow
def test_the_2d_task_goes_through_every_stage_and_draws_fig2(skilled_checkpoint, tmp_path, capsys):
    from lerobot_ccdp.benchmark import synthesis_cost

    work = tmp_path / "work"
    synthesis_cost.main(
        ["--tasks", "reaching2d", "--base", f"reaching2d={skilled_checkpoint}", "--recovery-steps", "4"]
        + ["--work", str(work)]
    )
    out = capsys.readouterr().out
    written = yaml.safe_load(
        (work / "reaching2d" / "recovery_data" / "meta" / "ccdp_recovery_recipe.yaml").read_text()
    )
    assert f"| reaching2d | {written['result']['pool_synthesised']} + " in out  # the stage table's row
    assert (work / "reaching2d" / "recovery" / "checkpoints" / "last" / "pretrained_model").is_dir()
    assert (work / "fig2_reaching2d.png").stat().st_size > 0
    for label, *_ in synthesis_cost.PANELS:  # one row per panel, DDIM and DDPM shares of the four goals
        row = next(line for line in out.splitlines() if line.startswith(f"| {label} |"))
        assert [len(cell.split(" / ")) for cell in row.split(" | ")[1:3]] == [4, 4]
