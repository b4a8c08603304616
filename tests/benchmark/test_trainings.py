"""`lerobot_ccdp.benchmark.trainings`: one table over three trainings' pipeline folders. The pooled figure is
every training's episodes together, each training's own figure is shown, intervals resample episodes within
each training, and evaluations of other seeds or a task or method one run lacks are refused."""

import dataclasses
from pprint import pformat

import numpy as np
import pytest

from lerobot_ccdp.benchmark.episodes import Episodes
from lerobot_ccdp.benchmark.paired import paired_difference, success_rate
from lerobot_ccdp.benchmark.pipeline import LABEL_FREE, task_slug
from lerobot_ccdp.benchmark.published import REPORT_NOTE
from lerobot_ccdp.benchmark.trainings import main

from fixtures.eval_runs import N, episodes, write_eval_info

BUTTONS, PACKING = "ButtonSearch-v0", "ObjectPacking-v0"
FIRST = 13000


def write_evaluation(run, task, method, found: Episodes, seed: int = FIRST, label_free: bool = False):
    """`found` as the pipeline leaves an evaluation in `run` (its --out): eval_info.json, and lerobot-eval's
    log, whose configuration (logged as LeRobot logs it, with a policy field also named seed) names the
    seed of the first episode."""
    folder = run / (task_slug(task) + (LABEL_FREE if label_free else ""))
    write_eval_info(folder / "eval" / method, found)
    config = {
        "env": {"task": task, "features_map": {"agent_pos": "observation.state", "action": "action"}},
        "policy": {"seed": 7, "recovery_mode": method, "n_obs_steps": 2, "horizon": 16},
        "output_dir": str(folder / "eval" / method),
        "seed": seed,
        "trust_remote_code": False,
    }
    (folder / "logs").mkdir(parents=True, exist_ok=True)
    (folder / "logs" / f"eval_{method}.log").write_text(
        f"INFO 2026-12-07 14:58:11 bot_eval.py:507 {pformat(config)}\nINFO Making environment.\n"
    )


def write_round(tmp_path, outcomes, task=BUTTONS, **kwargs) -> list[str]:
    """outcomes: method -> one Episodes per training; returns the runs' folders (seed0, seed1, ...)."""
    runs = [tmp_path / f"seed{k}" for k in range(len(next(iter(outcomes.values()))))]
    for method, per_run in outcomes.items():
        for run, found in zip(runs, per_run, strict=True):
            write_evaluation(run, task, method, found, **kwargs)
    return [str(run) for run in runs]


def rows(output: str) -> dict[str, list[str]]:
    """Table rows by their first cell, each row's cells."""
    cells = [line.strip("|").split(" | ") for line in output.splitlines() if line.startswith("| ")]
    return {row[0].strip(): [c.strip() for c in row[1:]] for row in cells}


def test_pooled_figures_are_every_episode_and_each_training_is_shown(tmp_path, capsys):
    outcomes = {
        "dp": [episodes(50, repeats=40), episodes(60, repeats=30), episodes(40, repeats=50)],
        "dp_star": [episodes(80), episodes(70), episodes(75)],
        "dp_star_matched": [episodes(60), episodes(65), episodes(55)],
        "ccdp": [episodes(90, repeats=10), episodes(80), episodes(70, repeats=20)],
    }
    runs = write_round(tmp_path, outcomes)
    main(["--runs", *runs])
    out = capsys.readouterr().out
    assert f"Seeds {FIRST}-{FIRST + N - 1}, 3 trainings (seed0 / seed1 / seed2), {3 * N} episodes" in out
    table = rows(out)
    for method, label in (("dp", "DP"), ("dp_star", "DP*"), ("dp_star_matched", "DP* at CCDP's cost")):
        pooled = np.concatenate([e.success for e in outcomes[method]]).mean()
        assert table[label][0].startswith(f"{pooled:.2f} [")
    # success: 240 of 300 pooled, each training's beside it; repeats: 30 over 3 x 200 attempts after a failure
    assert table["CCDP"][0].startswith("0.80 [") and table["CCDP"][1] == "0.90 / 0.80 / 0.70"
    assert table["CCDP"][2].startswith("0.05 [") and table["CCDP"][3] == "0.05 / 0.00 / 0.10"
    assert table["DP"][3] == "0.20 / 0.15 / 0.25"
    assert table["CCDP - DP"][0].startswith("0.30 [") and table["CCDP - DP"][1] == "0.40 / 0.20 / 0.30"
    assert table["CCDP - DP*"][1] == "0.10 / 0.10 / -0.05"
    assert table["CCDP - DP* at CCDP's cost"][0].startswith("0.20 [")
    assert "preference" not in out  # ButtonSearch's demonstrations prefer no option


def test_intervals_resample_within_trainings(tmp_path, capsys):
    """One training where CCDP solves every seed DP loses, one where both solve all: every stratified
    resample holds 100 episodes of each, so the pooled difference is 0.50 exactly, where a bootstrap of the
    200 episodes as one sample (the single-training path) would let their mix vary."""
    outcomes = {"dp": [episodes(0), episodes(N)], "ccdp": [episodes(N), episodes(N)]}
    runs = write_round(tmp_path, outcomes)
    main(["--runs", *runs])
    table = rows(capsys.readouterr().out)
    assert table["CCDP - DP"][:2] == ["0.50 [0.50, 0.50]", "1.00 / 0.00"]
    assert table["DP"][:2] == ["0.50 [0.50, 0.50]", "0.00 / 1.00"]
    ccdp, dp = (Episodes.concatenate(outcomes[m]) for m in ("ccdp", "dp"))
    unstratified = paired_difference(ccdp, dp, success_rate)
    assert unstratified.low < 0.45 and unstratified.high > 0.55


def test_columns_are_the_folders_the_runs_hold(tmp_path, capsys):
    """A CCDP form evaluated beside the others (the paper's eps_z heads, say) gets its rows with no change
    here, compared with every baseline; --methods keeps some; a preference task adds the preference
    difference on the episodes both solved; --label-free reads the label-free folders."""
    outcomes = {
        "dp_star": [episodes(80), episodes(70)],
        "ccdp": [episodes(90), episodes(80)],
        "ccdp_unet": [episodes(85), episodes(60)],
    }
    runs = write_round(tmp_path, outcomes, task=PACKING, label_free=True)
    main(["--runs", *runs, "--label-free"])
    table = rows(capsys.readouterr().out)
    assert table["ccdp_unet"][1] == "0.85 / 0.60"
    assert table["ccdp_unet - DP*"][1] == "0.05 / -0.10" and "CCDP - ccdp_unet" not in table
    assert table["CCDP - DP*"][4].startswith("0.00 [")  # both solved ones matched the preference alike
    main(["--runs", *runs, "--label-free", "--methods", "dp_star", "ccdp", "--tasks", PACKING])
    table = rows(capsys.readouterr().out)
    assert "ccdp_unet" not in table and "CCDP - DP*" in table
    with pytest.raises(SystemExit):
        main(["--runs", *runs])  # no labelled evaluation in these runs
    assert (
        "--runs hold no evaluation of any task: no folder <task>/eval (--label-free"
        in capsys.readouterr().err
    )


def test_other_seeds_or_a_missing_evaluation_are_refused(tmp_path, capsys):
    runs = write_round(tmp_path, {"dp": [episodes(50)] * 3, "ccdp": [episodes(90)] * 3})
    seed1 = tmp_path / "seed1"
    write_evaluation(tmp_path / "seed3", BUTTONS, "dp", episodes(50), seed=FIRST + N)
    write_evaluation(tmp_path / "seed3", BUTTONS, "ccdp", episodes(90), seed=FIRST + N)
    with pytest.raises(
        SystemExit, match=r"seed3: button_search's dp ran seeds 13100-13199 .*where .*seed0.s dp ran 13000"
    ):
        main(["--runs", *runs, str(tmp_path / "seed3")])
    fewer = episodes(90).subset(np.arange(N) < 50)
    (seed1 / "button_search" / "eval" / "ccdp" / "eval_info.json").unlink()
    (seed1 / "button_search" / "eval" / "ccdp").rmdir()
    write_evaluation(seed1, BUTTONS, "ccdp", fewer)
    with pytest.raises(
        SystemExit, match=r"seed1: button_search's ccdp ran seeds 13000-13049 \(50 episodes\)"
    ):
        main(["--runs", *runs])
    (seed1 / "button_search" / "logs" / "eval_ccdp.log").write_text("INFO a log without the config\n")
    with pytest.raises(SystemExit, match="cannot tell which seeds button_search's ccdp ran"):
        main(["--runs", *runs])
    (seed1 / "button_search" / "eval" / "ccdp" / "eval_info.json").unlink()
    with pytest.raises(SystemExit, match=r"seed1: button_search has no evaluation of ccdp .*--methods"):
        main(["--runs", *runs])
    write_evaluation(tmp_path / "seed2", PACKING, "dp", episodes(50))
    with pytest.raises(SystemExit, match=r"seed0 holds no evaluation of object_packing .*--tasks"):
        main(["--runs", *runs, "--methods", "dp"])
    with pytest.raises(SystemExit):
        main(["--runs", runs[0], runs[0]])
    assert "--runs names one folder twice" in capsys.readouterr().err


def test_publish_writes_its_own_file_and_no_other(tmp_path, capsys):
    runs = write_round(tmp_path, {"dp": [episodes(50)] * 2, "ccdp": [episodes(90)] * 2})
    target = tmp_path / "docs" / "trainings.md"
    main(["--runs", *runs, "--publish", str(target)])
    printed = capsys.readouterr().out
    text = target.read_text()
    assert (
        text.startswith(REPORT_NOTE) and "Command: `python -m lerobot_ccdp.benchmark.trainings --runs" in text
    )
    assert rows(text) == rows(printed) and "CCDP - DP" in rows(text)
    main(["--runs", *runs, "--publish", str(target)])  # its own file: replaced
    mine = tmp_path / "mine.md"
    mine.write_text("my notes\n")
    with pytest.raises(SystemExit, match="Refusing --publish .*lerobot_ccdp did not write it"):
        main(["--runs", *runs, "--publish", str(mine)])
    assert mine.read_text() == "my notes\n"


def test_preference_is_paired_on_the_episodes_both_solved_within_trainings(tmp_path, capsys):
    """ObjectPacking: CCDP's 20 extra successes of one training do not count; its 10 solved the wrong way
    among those both solved do."""
    ccdp = episodes(90)
    ccdp = dataclasses.replace(ccdp, preference_matched=ccdp.success & (np.arange(N) >= 10))
    runs = write_round(
        tmp_path, {"dp_star": [episodes(70), episodes(90)], "ccdp": [ccdp, ccdp]}, task=PACKING
    )
    main(["--runs", *runs])
    table = rows(capsys.readouterr().out)
    # 60 of 70 against 70 of 70; 80 of 90 against 90 of 90
    assert table["CCDP - DP*"][5] == "-0.14 / -0.11"
    assert table["CCDP - DP*"][4].startswith("-0.12 [")  # 140 of 160 against 160 of 160
