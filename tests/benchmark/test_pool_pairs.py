"""`benchmarks/pool_pairs.py` pools trainings seed by seed: each pair stays paired, and the pooled row is
the pairs' episodes together, not an average of their differences."""

import importlib.util
from pathlib import Path

import pytest

from fixtures.eval_runs import episodes, write_eval_info

REPO = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("pool_pairs", REPO / "benchmarks" / "pool_pairs.py")
pool = importlib.util.module_from_spec(spec)
spec.loader.exec_module(pool)


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


def test_pairs_of_other_seeds_or_no_evaluation_are_named(tmp_path):
    write_eval_info(tmp_path / "a", episodes(50))
    with pytest.raises(SystemExit, match="No eval_info.json in .*missing"):
        pool.main(["--pair", str(tmp_path / "a"), str(tmp_path / "missing")])
    write_eval_info(tmp_path / "b", episodes(50).subset(episodes(50).success))
    with pytest.raises(SystemExit, match="holds 100 episodes and .*b 50: pair evaluations of the same seeds"):
        pool.main(["--pair", str(tmp_path / "a"), str(tmp_path / "b")])
