"""`lerobot_ccdp.benchmark.pool_pairs` pools trainings seed by seed: each pair stays paired, and the pooled
row is the pairs' episodes together, not an average of their differences."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from lerobot_ccdp.benchmark import pool_pairs as pool
from lerobot_ccdp.benchmark import tune_methods as tune
from lerobot_ccdp.datasets.ownership import claim_output_folder

from fixtures.eval_runs import episodes, write_eval_info

REPO = Path(__file__).resolve().parents[2]


def test_each_pair_and_their_pool_are_variant_minus_reference(tmp_path, capsys):
    # Training 1: the variant solves 10 more and repeats less; training 2: the same success, 20 fewer repeats.
    runs = {
        "u1": episodes(70, repeats=30),
        "w1": episodes(80, repeats=10),
        "u2": episodes(60, repeats=40),
        "w2": episodes(60, repeats=20),
    }
    for name, found in runs.items():
        write_eval_info(tmp_path / name, found)
    pool.main(
        [
            "--pair",
            str(tmp_path / "u1"),
            str(tmp_path / "w1"),
            "--pair",
            str(tmp_path / "u2"),
            str(tmp_path / "w2"),
        ]
    )
    rows = {
        line.split(" | ")[0].strip("| "): line.split(" | ") for line in capsys.readouterr().out.splitlines()
    }
    assert rows["u1 / w1"][4].startswith("0.10 [") and rows["u2 / w2"][4].startswith("0.00 [")
    assert rows["pooled"][1] == "200" and rows["pooled"][4].startswith("0.05 [")
    # 20 + 20 fewer repeats over 2 x 200 attempts after a failure
    assert rows["pooled"][7].startswith("-0.10 [")


def test_preference_pairs_on_the_episodes_both_solved(tmp_path, capsys):
    """--preference adds preference adherence, paired on the episodes both evaluations solved: the variant's
    10 extra successes do not count, and its 20 solved the wrong way do."""
    reference, variant = episodes(80), episodes(90)
    variant = dataclasses.replace(variant, preference_matched=variant.success & (np.arange(100) >= 20))
    write_eval_info(tmp_path / "u", reference)
    write_eval_info(tmp_path / "w", variant)
    pool.main(["--pair", str(tmp_path / "u"), str(tmp_path / "w"), "--preference"])
    header, _, cells = capsys.readouterr().out.splitlines()
    assert header.count("preference: variant") == 1
    cells = cells.split(" | ")
    assert cells[8].startswith("0.78 [") and cells[9].startswith("1.00 [")  # 70 of 90, 80 of 80
    assert cells[10].startswith("-0.25 [")  # 60 of the 80 both solved, against 80 of them
    pool.main(["--pair", str(tmp_path / "u"), str(tmp_path / "w")])
    assert "preference" not in capsys.readouterr().out


def test_pairs_of_other_seeds_or_no_evaluation_are_named(tmp_path):
    write_eval_info(tmp_path / "a", episodes(50))
    with pytest.raises(SystemExit, match="No eval_info.json in .*missing"):
        pool.main(["--pair", str(tmp_path / "a"), str(tmp_path / "missing")])
    write_eval_info(tmp_path / "b", episodes(50).subset(episodes(50).success))
    with pytest.raises(SystemExit, match="holds 100 episodes and .*b 50: pair evaluations of the same seeds"):
        pool.main(["--pair", str(tmp_path / "a"), str(tmp_path / "b")])


def test_a_published_record_pairs_as_its_folders_did_and_is_never_replaced(tmp_path, capsys):
    """`tune_methods --publish` keeps a grid's episodes outside outputs/: pool_pairs reads an evaluation
    from the record exactly as from its folder, and an existing record is refused before anything runs."""
    out, task = tmp_path / "run", "DoorOpening-lite-v0"
    claim_output_folder(out, tune.CREATED_BY)
    files = tune.TaskFiles.locate(task, REPO / "configs", REPO / "datasets_recipes", out)
    (files.out / "recovery" / tune.CHECKPOINT).mkdir(parents=True)
    folders = {}
    for w_z, found in ((5, episodes(70, repeats=30)), (1, episodes(80, repeats=10))):
        folders[w_z] = tune.run_dir(files, "ccdp", tune.OWN, (("w_z", w_z),), 1000)
        write_eval_info(folders[w_z], found)
    write_eval_info(tune.run_dir(files, "dp_star", tune.OWN, (), 1000), episodes(60))
    record = tmp_path / "docs" / "development" / "run.json"
    grid = ["--out", str(out), "--tasks", task, "--method", "ccdp", "--grid", "w_z=5,1", "--report-only"]
    tune.main([*grid, "--against", "dp_star", "--publish", str(record)])
    keys = {w_z: f"{record}:{task}/tune_ccdp/{folders[w_z].name}" for w_z in folders}
    capsys.readouterr()
    pool.main(["--pair", str(folders[5]), str(folders[1])])
    from_folders = capsys.readouterr().out.splitlines()[-1].split(" | ")[1:]
    dp_star = f"{record}:{task}/tune_dp_star/frozen_seed1000"
    pool.main(["--pair", keys[5], keys[1], "--pair", dp_star, keys[1]])
    rows = capsys.readouterr().out.splitlines()
    assert rows[2].split(" | ")[1:] == from_folders and rows[2].split(" | ")[4].startswith("0.10 [")
    assert rows[3].split(" | ")[4].startswith("0.20 [")  # against DP*'s 60
    with pytest.raises(SystemExit, match="No evaluation 'DoorOpening-lite-v0/tune_ccdp/nothing' in .*holds"):
        pool.main(["--pair", keys[5], f"{record}:{task}/tune_ccdp/nothing"])
    with pytest.raises(SystemExit, match="--publish .*run.json exists; name a new file"):
        tune.main([*grid, "--publish", str(record)])
