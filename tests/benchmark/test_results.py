"""docs/results.md from saved runs: round trip, the hybrid's name, the claims, refusals, what is published."""

import subprocess
from pathlib import Path

import numpy as np
import pytest

from lerobot_ccdp.benchmark.comparison import METHOD_LABELS
from lerobot_ccdp.benchmark.episodes import Episodes
from lerobot_ccdp.benchmark.paired import paired_difference, success_rate
from lerobot_ccdp.benchmark.pipeline import TASK_GROUPS
from lerobot_ccdp.benchmark.results import (
    README_BEGIN,
    README_END,
    Run,
    claims_table,
    command_line,
    commit,
    main,
    save_run,
    seeds,
    table,
)
from lerobot_ccdp.benchmark.rounds import EARLY, FAMILY_ROUNDS, ROUNDS

# The name a published run of CCDP with its plans redrawn through DP*'s outcome lookup carries.
HYBRID = "CCDP + 16 redraws (DP*'s lookup)"


def _episodes(success: list[bool], failures: list[float]) -> Episodes:
    n = len(success)
    return Episodes(
        success=np.array(success),
        attempts=np.array([2] * n),
        repeated_failures=np.array([0] * n),
        preference_matched=np.array(success),
        attempts_after_failure=np.array([1.0] * n),
        failures=np.array(failures, dtype=float),
    )


def _saved(path, ccdp_labels: dict[str, str]) -> Run:
    episodes, labels = {}, {}
    for i, (task, label) in enumerate(ccdp_labels.items()):
        episodes[task] = {
            "dp": _episodes([True, False, False, True], [1, 2, 2, 0]),
            "ccdp": _episodes([True, True, False, True], [1, 1, np.nan if i else 2, 0]),
        }
        labels[task] = {"dp": "DP", "ccdp": label}
    save_run(path, episodes, labels, "python -m lerobot_ccdp.benchmark.pipeline --tasks x", 3000)
    return Run.load(path)


def test_a_saved_run_loads_back_with_its_missing_values(tmp_path):
    run = _saved(tmp_path / "run.json", {"DoorOpening-v0": "CCDP", "ButtonSearch-v0": "CCDP"})
    assert run.first_seeds == {"DoorOpening-v0": 3000, "ButtonSearch-v0": 3000}
    assert run.origins[0].command.endswith("--tasks x")
    door = run.episodes["DoorOpening-v0"]["ccdp"]
    assert door.success.dtype == bool and list(door.failures) == [1, 1, 2, 0]
    assert np.isnan(run.episodes["ButtonSearch-v0"]["ccdp"].failures[2])  # NaN survives JSON as null


def test_the_table_names_the_hybrid_and_pairs_episodes_by_seed(tmp_path):
    label = HYBRID
    run = _saved(tmp_path / "run.json", {"ObjectPacking-v0": label})
    lines = table(run).splitlines()
    assert lines[0] == f"| task | DP | {label} | {label} - DP |"
    gap = paired_difference(
        run.episodes["ObjectPacking-v0"]["ccdp"], run.episodes["ObjectPacking-v0"]["dp"], success_rate
    )
    assert lines[2] == f"| ObjectPacking | 0.50 / 0.00 | 0.75 / 0.00 | {gap} |"


def test_the_eps_z_column_stands_beside_ccdp_with_its_paired_difference(tmp_path):
    """A run with eq. (4)'s eps_z heads (`ccdp_eps_z`) shows them as a column of their own after CCDP, CCDP's
    differences against the baselines unchanged and one more against them, paired by seed; a task that did not
    run them shows "-"."""
    eps_z = _episodes([True, False, False, False], [1, 2, 2, 2])
    episodes = {
        "ButtonSearch-v0": {
            "dp": _episodes([True, False, False, True], [1, 2, 2, 0]),
            "ccdp": _episodes([True, True, False, True], [1, 1, 2, 0]),
            "ccdp_eps_z": eps_z,
        },
        "DoorOpening-v0": {
            "dp": _episodes([True, False, False, True], [1, 2, 2, 0]),
            "ccdp": _episodes([True, True, True, True], [1, 1, 1, 0]),
        },
    }
    labels = {task: {m: METHOD_LABELS[m] for m in ms} for task, ms in episodes.items()}
    save_run(tmp_path / "run.json", episodes, labels, "python -m lerobot_ccdp.benchmark.pipeline", 3000)
    run = Run.load(tmp_path / "run.json")
    lines = table(run).splitlines()
    label = "CCDP, eq. (4) eps_z heads"
    assert lines[0] == f"| task | DP | CCDP | {label} | CCDP - DP | CCDP - {label} |"
    buttons = episodes["ButtonSearch-v0"]
    to_dp = paired_difference(buttons["ccdp"], buttons["dp"], success_rate)
    to_eps_z = paired_difference(buttons["ccdp"], eps_z, success_rate)
    assert lines[2] == f"| ButtonSearch | 0.50 / 0.00 | 0.75 / 0.00 | 0.25 / 0.00 | {to_dp} | {to_eps_z} |"
    door = lines[3]
    assert door.startswith("| DoorOpening | 0.50 / 0.00 | 1.00 / 0.00 | - | ") and door.endswith(" | - |")


def test_the_seeds_are_named_per_task_where_a_round_sized_its_tasks_differently(tmp_path):
    run = _saved(tmp_path / "run.json", {"DoorOpening-v0": "CCDP", "Bartender-v0": "CCDP"})
    assert seeds(run) == "3000-3003"
    longer = {m: _episodes([True] * 6, [0] * 6) for m in ("dp", "ccdp")}
    labels = {task: {"dp": "DP", "ccdp": "CCDP"} for task in run.episodes}
    save_run(tmp_path / "sized.json", {**run.episodes, "Bartender-v0": longer}, labels, "pipeline", 3000)
    assert seeds(Run.load(tmp_path / "sized.json")) == "DoorOpening 3000-3003, Bartender 3000-3005"


def test_a_round_published_task_by_task_is_one_table_that_names_each_file(tmp_path):
    """--publish-each writes a run file per task; `--run TITLE a.json b.json` tabulates them as one run."""
    folder = tmp_path / "docs" / "benchmark"
    folder.mkdir(parents=True)
    door = _saved(folder / "DoorOpening-v0.json", {"DoorOpening-v0": "CCDP"})
    bartender = _saved(folder / "Bartender-v0.json", {"Bartender-v0": "CCDP"})
    out = tmp_path / "docs" / "results.md"
    main(
        [
            "--run",
            "Round",
            str(folder / "DoorOpening-v0.json"),
            str(folder / "Bartender-v0.json"),
            "--out",
            str(out),
        ]
    )
    written = out.read_text()
    assert "Made task by task:" in written
    for task in ("DoorOpening-v0", "Bartender-v0"):  # linked from docs/results.md's folder
        assert f"--tasks x`; per-episode outcomes: [benchmark/{task}.json](benchmark/{task}.json)" in written
        assert f"- {task}: at commit `" in written  # each file's line names its task
    merged = Run.load(folder / "DoorOpening-v0.json", folder / "Bartender-v0.json")
    assert table(merged).splitlines()[2:] == [table(door).splitlines()[2], table(bartender).splitlines()[2]]
    with pytest.raises(ValueError, match=r"repeats \['DoorOpening-v0'\]"):
        Run.load(folder / "DoorOpening-v0.json", folder / "DoorOpening-v0.json")
    # a later round of one task keeps its own seeds, and the seed line names each task's range
    save_run(tmp_path / "later.json", door.episodes, door.labels, "pipeline", 5000)
    assert seeds(Run.load(folder / "Bartender-v0.json", tmp_path / "later.json")) == (
        "Bartender 3000-3003, DoorOpening 5000-5003"
    )
    with pytest.raises(SystemExit, match="2"):
        main(["--run", "Round", "--out", str(out)])  # a title without a run file


def test_the_results_list_every_test_round_with_its_count(tmp_path):
    """Whatever runs make the tables, docs/results.md lists every round ever run, one line each, and how many
    each task and label setting has had (the generator writes it, so `make results` keeps it)."""
    _saved(tmp_path / "run.json", {"DoorOpening-v0": "CCDP"})
    out = tmp_path / "results.md"
    main(["--run", "Round", str(tmp_path / "run.json"), "--out", str(out)])
    listed = out.read_text().split("## Every test round", 1)[1]
    rows = [line for line in listed.splitlines() if line.startswith("| ") and not line.startswith("| task ")]
    rows = [row for row in rows if not row.startswith("| members ")]
    assert len(rows) == len(ROUNDS) + len(EARLY) + len(FAMILY_ROUNDS)
    counted = dict(
        item.rsplit(" ", 1)
        for item in listed.split("Rounds per task and label setting: ")[1].split(".")[0].split("; ")
    )
    declared = rows[: len(ROUNDS)]
    assert {title: int(n) for title, n in counted.items()} == {
        title: sum(row.startswith(f"| {title} |") for row in declared) for title in counted
    }
    assert sum(map(int, counted.values())) == len(ROUNDS)
    assert "| ObjectPacking, labels | 3000-3099 | `a036af1` | missed: non-inferiority -0.12" in listed
    assert "| Bartender, no labels | 12400-12999 | `5a35c59` | all met |" in listed


def test_one_table_never_mixes_ccdp_and_a_hybrid(tmp_path):
    run = _saved(tmp_path / "run.json", {"DoorOpening-v0": "CCDP", "Bartender-v0": HYBRID})
    with pytest.raises(ValueError, match="hybrid gets its own column"):
        table(run)


def test_the_command_refuses_a_readme_without_the_markers_and_other_files(tmp_path):
    _saved(tmp_path / "run.json", {"DoorOpening-v0": "CCDP"})
    readme, results = tmp_path / "README.md", tmp_path / "r.md"
    command = ["--run", "Door", str(tmp_path / "run.json"), "--out", str(results), "--readme", str(readme)]
    readme.write_text("# no markers\n")
    with pytest.raises(SystemExit, match="has no block for this table"):
        main(command)
    assert not results.exists()  # nothing written when the README cannot take the table
    (tmp_path / "other.json").write_text('{"task": {}}')
    with pytest.raises(SystemExit, match="not a run saved by the pipeline"):
        main(["--run", "Door", str(tmp_path / "other.json"), "--out", str(results)])
    readme.write_text(f"intro\n{README_BEGIN}\n{README_END}\nend\n")
    main(command)
    assert readme.read_text().startswith(f"intro\n{README_BEGIN}\n| task | DP | CCDP | CCDP - DP |")
    assert readme.read_text().endswith(f"{README_END}\nend\n")


def test_the_claims_are_judged_as_issue_50_defines_them(tmp_path):
    half, every = [True, False] * 20, [True] * 40
    repeats = _episodes(every, [1.0] * 40)
    repeats.repeated_failures[:] = 1  # one repeat per attempt after a failure
    episodes = {
        "DoorOpening-v0": {  # CCDP as DP*, above DP and above DP* at CCDP's cost
            "dp": _episodes(half, [1.0] * 40),
            "dp_star": _episodes(every, [1.0] * 40),
            "dp_star_matched": _episodes(half, [1.0] * 40),
            "ccdp": _episodes(every, [1.0] * 40),
        },
        "Bartender-v0": {  # CCDP as DP, repeating; DP* no better than DP: nothing to add over matched
            "dp": _episodes(half, [1.0] * 40),
            "dp_star": _episodes(half, [1.0] * 40),
            "dp_star_matched": _episodes(half, [1.0] * 40),
            "ccdp": repeats,
        },
    }
    episodes["Bartender-v0"]["ccdp"].success[:] = half
    episodes["Bartender-v0"]["ccdp"].preference_matched[:] = False  # never the demonstrated preference
    labels = {task: dict.fromkeys(methods, "CCDP") for task, methods in episodes.items()}
    save_run(tmp_path / "run.json", episodes, labels, "python -m lerobot_ccdp.benchmark.pipeline", 3000)
    lines = claims_table(Run.load(tmp_path / "run.json")).splitlines()
    assert lines[0].startswith("| task | CCDP - DP* >= -0.05 | repeats after a failure <= 0.05 (upper bound")
    door, bartender = (line.removesuffix(" |").split(" | ")[1:] for line in lines[2:])
    assert [cell.split(",")[0] for cell in door] == ["met"] * 4 + ["-"]  # the door has no preference
    assert [cell.split(",")[0] for cell in bartender] == ["met", "missed", "missed", "-", "missed"]
    without = {task: {m: e for m, e in ms.items() if m != "dp_star_matched"} for task, ms in episodes.items()}
    save_run(tmp_path / "two.json", without, labels, "python -m lerobot_ccdp.benchmark.pipeline", 3000)
    assert claims_table(Run.load(tmp_path / "two.json")) == ""  # a run without every baseline has no claims


def test_the_published_tables_are_what_make_results_writes(tmp_path):
    """docs/results.md and the README's block equal `make results` on the committed run files."""
    docs = Path(__file__).parents[2] / "docs"
    readme = tmp_path / "README.md"
    readme.write_text((docs.parent / "README.md").read_text())
    mirror = tmp_path / "docs"  # the run files where docs/ has them, so that results.md links them alike
    for run_file in docs.rglob("*.json"):
        (mirror / run_file.relative_to(docs)).parent.mkdir(parents=True, exist_ok=True)
        (mirror / run_file.relative_to(docs)).symlink_to(run_file)
    runs = {
        "With option labels (make benchmark)": "benchmark",
        "Without labels (make benchmark-label-free)": "benchmark_label_free",
    }
    args = ["--readme", str(readme), "--out", str(mirror / "results.md")]
    for title, folder in runs.items():
        args += ["--run", title, *(str(mirror / folder / f"{task}.json") for task in TASK_GROUPS["all"])]
    main(args)
    written, published = ((p / "results.md").read_text().splitlines() for p in (mirror, docs))
    assert [line for line in written if not line.startswith("<!-- Written")] == [
        line for line in published if not line.startswith("<!-- Written")
    ]
    assert readme.read_text() == (docs.parent / "README.md").read_text()


def test_the_commit_is_marked_dirty_by_code_changes_only(tmp_path, monkeypatch):
    """Two runs publishing into one tree: the first's docs must not mark the second's commit as changed."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "docs").mkdir()
    for name in ("code.py", "README.md", "docs/report.md"):
        (tmp_path / name).write_text("first\n")
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(["git", "init", "-q"], check=True)
    subprocess.run([*git, "add", "."], check=True)
    subprocess.run([*git, "commit", "-qm", "first"], check=True)
    clean = commit()
    (tmp_path / "docs" / "report.md").write_text("published\n")
    (tmp_path / "README.md").write_text("published\n")
    assert commit() == clean and "uncommitted" not in clean
    (tmp_path / "code.py").write_text("changed\n")
    assert commit() == f"{clean} + uncommitted changes"


def test_a_published_command_names_no_checkout_path(tmp_path, monkeypatch):
    """The published reports named the machine's checkout (`--out /work/main/outputs/...`): paths under the
    working directory are spelled relative to it, others and non-path arguments kept as given."""
    monkeypatch.chdir(tmp_path)
    argv = [
        "--out",
        str(tmp_path / "outputs" / "b"),
        f"--publish-each={tmp_path}/docs/x",
        "--tasks",
        "A B",
        "/etc",
    ]
    assert command_line("python -m lerobot_ccdp.benchmark.pipeline", argv) == (
        "python -m lerobot_ccdp.benchmark.pipeline --out outputs/b --publish-each=docs/x --tasks 'A B' /etc"
    )
