"""`lerobot_ccdp.benchmark.tune_methods` keeps the grid's first setting unless a paired interval says another
is better: a higher mean that the development seeds cannot tell from noise is a tie, not a win (issue 17's
honest comparison)."""

import dataclasses
import subprocess
from pathlib import Path

import numpy as np
import pytest

from lerobot_ccdp.benchmark import tune_methods as tune
from lerobot_ccdp.benchmark.episodes import Episodes
from lerobot_ccdp.datasets.ownership import claim_output_folder

from fixtures.eval_runs import N, episodes, write_eval_info

REPO = Path(__file__).resolve().parents[2]

FIRST, OTHER = ("recovery", (("w_z", 3),)), ("recovery", (("w_z", 1),))


def test_a_higher_mean_success_within_noise_keeps_the_first_setting():
    # Paired: OTHER solves 12 episodes FIRST lost and loses 8 that FIRST solved (+0.04, an interval across 0).
    row, why = tune.pick([FIRST, OTHER], {FIRST: episodes(60), OTHER: episodes(64, shift=8)})
    assert row == FIRST and "first setting" in why


def test_a_success_gain_clear_of_zero_wins():
    row, why = tune.pick([FIRST, OTHER], {FIRST: episodes(50), OTHER: episodes(70)})
    assert row == OTHER and why.startswith("success 0.20")


def test_fewer_repeats_win_a_success_tie_but_not_a_clear_success_loss():
    pooled = {FIRST: episodes(60, repeats=30), OTHER: episodes(60, repeats=2)}
    row, why = tune.pick([FIRST, OTHER], pooled)
    assert row == OTHER and why.startswith("repeats -0.14")
    pooled[OTHER] = episodes(40, repeats=2)
    assert tune.pick([FIRST, OTHER], pooled)[0] == FIRST


def test_pooling_tasks_concatenates_their_episodes_in_order():
    a, b = episodes(10, repeats=1), episodes(90)
    both = Episodes.concatenate([a, b])
    assert len(both) == 2 * N and both.success.sum() == 100 and both.repeated_failures[:N].sum() == 1


def test_heads_choose_which_checkpoints_are_evaluated_and_the_first_is_the_reference():
    grid = tune.parse_grid(["w_z=1,3"])
    checkpoints = {"classifier": "outputs/classifier/{slug}"}
    every = tune.table_rows(grid, checkpoints, None)
    assert [name for name, _ in every] == ["recovery", "recovery", "classifier", "classifier"]
    only = tune.table_rows(grid, checkpoints, ["classifier"])
    assert only == [("classifier", (("w_z", 1),)), ("classifier", (("w_z", 3),))]
    assert tune.table_rows(grid, checkpoints, ["classifier", "recovery"])[0][0] == "classifier"


def test_heads_refuses_a_head_without_a_checkpoint():
    with pytest.raises(SystemExit, match="mlp.*--checkpoint NAME=PATH"):
        tune.table_rows(tune.parse_grid(["w_z=1"]), {"classifier": "x"}, ["mlp"])


def test_seeds_for_non_inferiority_follow_the_difference_and_its_spread():
    """`--against`'s last column: a method 0.02 ahead with 10 + 8 discordant seeds of 100 needs about
    (1.96 * sd / 0.07)^2 seeds; one 0.05 behind can never show non-inferiority at margin 0.05; agreeing
    seeds need fewer."""
    from lerobot_ccdp.benchmark.paired import seeds_for_non_inferiority

    reference = episodes(70)
    ahead = episodes(72, shift=8)  # solves 10 the reference lost, loses 8 it solved
    d = ahead.success.astype(float) - reference.success.astype(float)
    assert d.mean() == pytest.approx(0.02)
    expected = np.ceil((1.96 * d.std(ddof=1) / 0.07) ** 2)
    assert seeds_for_non_inferiority(ahead, reference, 0.05) == expected
    assert seeds_for_non_inferiority(episodes(65, shift=8), reference, 0.05) == np.inf
    closer = episodes(72, shift=1)  # 3 and 1 discordant: same mean, less spread
    assert seeds_for_non_inferiority(closer, reference, 0.05) < expected
    cells = tune.against(ahead, reference, False).split(" | ")
    assert cells[1].startswith("0.02 [") and cells[3] == f"{expected:.0f}" and cells[4] == "-"


def test_dp_and_the_frozen_settings_evaluate_on_every_head_with_preference_against_dp_star(tmp_path, capsys):
    """No --grid is the methods.json settings, the one form of DP: DP on two heads (two bases, say) pairs
    head by head. --against adds preference adherence on a task with a preference, paired on the episodes
    both solved. DP takes no grid and nothing frozen is written back."""
    out, task = tmp_path / "run", "Bartender-lite-v0"
    claim_output_folder(out, tune.CREATED_BY)
    files = tune.TaskFiles.locate(task, REPO / "configs", REPO / "datasets_recipes", out)
    (files.out / "recovery" / tune.CHECKPOINT).mkdir(parents=True)
    (tmp_path / "longer").mkdir()
    write_eval_info(tune.run_dir(files, "dp", tune.OWN, (), 1000), episodes(60))
    longer = episodes(70)
    longer = dataclasses.replace(longer, preference_matched=longer.success & (np.arange(100) >= 10))
    write_eval_info(tune.run_dir(files, "dp", "b2", (), 1000), longer)
    write_eval_info(tune.run_dir(files, "dp_star", tune.OWN, (), 1000), episodes(80))
    args = ["--out", str(out), "--tasks", task, "--method", "dp", "--checkpoint", f"b2={tmp_path / 'longer'}"]
    tune.main([*args, "--report-only", "--against", "dp_star"])
    printed = capsys.readouterr().out
    row = next(line for line in printed.splitlines() if line.startswith(f"| {task} | b2: methods.json |"))
    assert row.split(" | ")[2].startswith("0.70") and row.split(" | ")[3].startswith("0.10 [")  # b2 - own
    against = next(line for line in printed.splitlines() if "| b2: methods.json | 0.80" in line)
    assert against.split(" | ")[-1].startswith("-0.14 [")  # 60 of the 70 both solved matched, against 70
    with pytest.raises(SystemExit, match="DP has no settings to tune; give no --grid"):
        tune.main([*args, "--report-only", "--grid", "w_z=1"])
    with pytest.raises(SystemExit, match="--write without --grid"):
        tune.main([*args, "--report-only", "--write"])


def test_the_development_size_is_its_own_and_a_saved_evaluation_of_another_size_is_refused(tmp_path, capsys):
    """A round sized 600 in the eval config still tunes on 100 development seeds, and a saved evaluation of
    another size is named rather than paired against one of 100."""
    out = tmp_path / "run"
    claim_output_folder(out, tune.CREATED_BY)
    task = "DoorOpening-lite-v0"
    files = tune.TaskFiles.locate(task, REPO / "configs", REPO / "datasets_recipes", out)
    (files.out / "recovery" / tune.CHECKPOINT).mkdir(parents=True)
    run = ["--out", str(out), "--tasks", task, "--method", "ccdp", "--grid", "w_z=5", "--report-only"]
    write_eval_info(tune.run_dir(files, "ccdp", tune.OWN, (("w_z", 5),), 1000), episodes(100))
    tune.main(run)
    assert "ccdp on seeds 1000-1099" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="holds 100 episodes, not --episodes 60"):
        tune.main([*run, "--episodes", "60"])
    with pytest.raises(SystemExit, match="at least one episode"):
        tune.main([*run, "--episodes", "0"])


def test_a_baseline_run_pairs_each_row_and_the_reference_method_by_seed(tmp_path, capsys):
    """Two runs (other demos, say) tuned with the same grid and seeds compare seed by seed: this run minus the
    other, for the tuned method and for --against's; an evaluation missing there is named, not skipped."""
    task = "DoorOpening-lite-v0"
    run, base = tmp_path / "run", tmp_path / "base"
    found = {}
    for folder, ccdp_wins in ((run, 80), (base, 60)):
        claim_output_folder(folder, tune.CREATED_BY)
        files = tune.TaskFiles.locate(task, REPO / "configs", REPO / "datasets_recipes", folder)
        (files.out / "recovery" / tune.CHECKPOINT).mkdir(parents=True)
        write_eval_info(tune.run_dir(files, "ccdp", tune.OWN, (("w_z", 5),), 1000), episodes(ccdp_wins))
        found[folder] = files
    write_eval_info(tune.run_dir(found[run], "dp_star", tune.OWN, (), 1000), episodes(70, repeats=10))
    args = ["--out", str(run), "--tasks", task, "--method", "ccdp", "--grid", "w_z=5", "--report-only"]
    with pytest.raises(SystemExit, match="No evaluation of dp_star .* run this grid on --out .*base"):
        tune.main([*args, "--against", "dp_star", "--baseline-run", str(base)])
    write_eval_info(tune.run_dir(found[base], "dp_star", tune.OWN, (), 1000), episodes(70))
    tune.main([*args, "--against", "dp_star", "--baseline-run", str(base)])
    table = capsys.readouterr().out.split(f"Against the same evaluations of {base}")[1]
    ccdp_row = next(line for line in table.splitlines() if "| ccdp w_z 5 |" in line).split(" | ")
    dp_star_row = next(line for line in table.splitlines() if "dp_star (methods.json)" in line).split(" | ")
    assert ccdp_row[2].startswith("0.80") and ccdp_row[3].startswith("0.60")
    assert ccdp_row[4].startswith("0.20 [")
    assert dp_star_row[4].startswith("0.00 [")  # 10 repeats over 200 attempts after a failure, here only:
    assert dp_star_row[5].startswith("0.05") and dp_star_row[7].startswith("0.05 [")
    with pytest.raises(SystemExit, match="is --out itself"):
        tune.main([*args, "--baseline-run", str(run)])


def test_the_eps_z_column_is_tuned_on_its_own_heads_against_ccdp_on_the_tasks(tmp_path, capsys, monkeypatch):
    """`--method ccdp_eps_z` evaluates the eps_z heads a pipeline run trained for that column
    (`<task>/recovery_eps_z`) with CCDP's sampling, and `--against ccdp` the task's own head
    (`<task>/recovery`), on the same seeds; a run without the eps_z heads is named with the pipeline flag
    that trains them."""
    out, task = tmp_path / "run", "DoorOpening-lite-v0"
    claim_output_folder(out, tune.CREATED_BY)
    files = tune.TaskFiles.locate(task, REPO / "configs", REPO / "datasets_recipes", out)
    (files.out / "recovery" / tune.CHECKPOINT).mkdir(parents=True)
    args = ["--out", str(out), "--tasks", task, "--method", "ccdp_eps_z", "--grid", "w_z=1,3"]
    with pytest.raises(SystemExit, match=r"recovery_eps_z/.*--methods ccdp_eps_z"):
        tune.main([*args, "--against", "ccdp"])
    (files.out / "recovery_eps_z" / tune.CHECKPOINT).mkdir(parents=True)
    commands = []

    def lerobot_eval(command: list[str], **_) -> subprocess.CompletedProcess:
        """lerobot-eval faked: its command kept, and its output folder given the episodes of 60 wins."""
        commands.append(command)
        write_eval_info(Path(flag(command, "--output_dir")), episodes(60))
        return subprocess.CompletedProcess(command, 0, "", "")

    monkeypatch.setattr(tune.subprocess, "run", lerobot_eval)
    tune.main([*args, "--against", "ccdp"])
    evaluated = {Path(flag(c, "--output_dir")).parent.name: c for c in commands}
    assert [Path(flag(c, "--output_dir")).name for c in commands] == [
        "frozen_seed1000",  # --against's, then the grid's
        "w_z1_seed1000",
        "w_z3_seed1000",
    ]
    eps_z, ccdp = evaluated["tune_ccdp_eps_z"], evaluated["tune_ccdp"]
    assert flag(eps_z, "--policy.path") == str(files.out / "recovery_eps_z" / tune.CHECKPOINT)
    assert flag(ccdp, "--policy.path") == str(files.out / "recovery" / tune.CHECKPOINT)
    for command in (eps_z, ccdp):
        assert (
            flag(command, "--policy.recovery_mode") == "ccdp" and "--policy.row_noise_streams=true" in command
        )
        assert flag(command, "--seed") == "1000"
    assert "pick for ccdp_eps_z: w_z 1" in capsys.readouterr().out


def flag(command: list[str], name: str) -> str:
    """The value of `name`=... in `command`."""
    return next(arg.split("=", 1)[1] for arg in command if arg.startswith(f"{name}="))
