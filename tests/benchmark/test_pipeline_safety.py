"""The pipeline writes into and deletes only output folders it made (issue 49): `--fresh` on a user's folder,
the working directory or the home folder deletes nothing, and an output folder is one folder however it is
spelled, for its lock and its stage stamps. The stages are faked (each makes the output its stage checks for),
so these run in seconds; tests/benchmark/test_pipeline.py runs the real ones."""

import fcntl
import json
import os
import re
import shutil
import threading
import time
from pathlib import Path

import pytest

from lerobot_ccdp.benchmark import pipeline, results, run_lock
from lerobot_ccdp.benchmark.comparison import MethodMetrics, bar_chart
from lerobot_ccdp.benchmark.pipeline import (
    CHECKPOINT,
    CREATED_BY,
    RUN_FILE,
    PipelineError,
    TaskFiles,
    TaskRun,
    main,
    publish_report,
    task_slug,
)
from lerobot_ccdp.benchmark.published import REPORT_NOTE
from lerobot_ccdp.benchmark.run_lock import PipelineRunning, exclusive
from lerobot_ccdp.datasets.ownership import MARKER, NotOwned, claim_output_folder, owner

REPO = Path(__file__).resolve().parents[2]
TASK = "DoorOpening-lite-v0"
SLUG = task_slug(TASK)
# What each faked stage makes: the folder its command names, and the file in it that marks the stage done.
OUTPUTS = {
    "lerobot-ccdp-record": ("--dataset.root", "meta/info.json"),
    "lerobot-ccdp-synthesize": ("--output.root", "meta/info.json"),
    "lerobot-train": ("--output_dir", f"{CHECKPOINT}/model.safetensors"),
}


class FakeStages:
    """`run_with_progress` without the CLIs: records each command and makes its output, or fails if told."""

    def __init__(self) -> None:
        self.commands: list[list[str]] = []
        self.exit_code = 0

    def __call__(self, command: list[str], log: Path, label: str, threads: int | None = None) -> int:
        self.commands.append(command)
        log.write_text("faked\n")
        if self.exit_code == 0:
            flag, done = OUTPUTS[Path(command[0]).name]
            folder = next(arg.split("=", 1)[1] for arg in command if arg.startswith(f"{flag}="))
            (Path(folder) / done).parent.mkdir(parents=True, exist_ok=True)
            (Path(folder) / done).touch()
        return self.exit_code


@pytest.fixture
def stages(monkeypatch) -> FakeStages:
    fake = FakeStages()
    monkeypatch.setattr(pipeline, "run_with_progress", fake)
    return fake


@pytest.fixture
def root(tmp_path, monkeypatch) -> Path:
    """The working directory of a test, holding the task's settings under `settings/`."""
    tmp_path = tmp_path.resolve()
    (tmp_path / "settings" / "recipes").mkdir(parents=True)
    shutil.copytree(REPO / "configs" / SLUG, tmp_path / "settings" / "configs" / SLUG)
    shutil.copy(REPO / "datasets_recipes" / f"{SLUG}.yaml", tmp_path / "settings" / "recipes")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def run(out: str | Path, *extra: str, settings: str | Path = "settings", train_only: bool = True) -> None:
    """The pipeline's training stages (or with `train_only` False every stage) on `out`, the settings spelled
    from `settings`."""
    main(
        [
            "--tasks",
            TASK,
            "--out",
            str(out),
            "--configs",
            f"{settings}/configs",
            "--recipes",
            f"{settings}/recipes",
            *(["--train-only"] if train_only else []),
            *extra,
        ]
    )


def user_folder(path: Path) -> Path:
    """A folder a user made: a file and a git repository."""
    (path / ".git").mkdir(parents=True)
    (path / ".git" / "HEAD").write_text("ref: refs/heads/main\n")
    (path / "keep.txt").write_text("mine")
    return path


def untouched(path: Path) -> bool:
    names = sorted(p.name for p in path.iterdir())
    return names == [".git", "keep.txt"] and (path / "keep.txt").read_text() == "mine"


def test_fresh_refuses_a_folder_without_the_marker_and_deletes_nothing(root, stages):
    mine = user_folder(root / "mine")
    with pytest.raises(
        SystemExit,
        match=re.escape(f"Refusing --out {mine}: it holds files and no {MARKER}")
        + r".*Nothing was deleted.*--fresh deletes only a folder this command made",
    ):
        run(mine, "--fresh")
    assert untouched(mine) and not stages.commands
    assert not (root / ".mine.pipeline.lock").exists()  # refused before the lock


def test_an_unmarked_folder_holding_files_is_refused_unless_adopted(root, stages):
    mine = user_folder(root / "mine")
    with pytest.raises(SystemExit, match=r"Nothing was deleted or written.*rerun with --adopt"):
        run("mine")
    assert untouched(mine) and not stages.commands
    run("mine", "--adopt")  # an output folder of an earlier version: resumed, and marked from then on
    assert (mine / "keep.txt").read_text() == "mine" and len(stages.commands) == 4
    run("mine")
    assert len(stages.commands) == 4


def test_a_moved_output_folder_is_refused_until_adopted_again(root, stages):
    run("out")
    (root / "out").rename(root / "moved")
    with pytest.raises(
        SystemExit, match=r"a moved or copied output folder carries the mark of its old place"
    ):
        run("moved")
    run("moved", "--adopt")
    assert owner(root / "moved") == CREATED_BY


@pytest.mark.parametrize("place", ["working directory", "its parent", "home folder"])
def test_fresh_never_deletes_the_working_directory_its_parents_or_home_even_marked(
    root, stages, monkeypatch, place
):
    home, work = root / "home", root / "work" / "sub"
    for folder in (home, work):
        folder.mkdir(parents=True)
        claim_output_folder(folder, CREATED_BY)
        (folder / "keep.txt").write_text("mine")
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(work)
    out = {"working directory": ".", "its parent": "..", "home folder": "~"}[place]
    with pytest.raises(
        SystemExit,
        match=r"is or holds the working directory or the home folder, which --fresh "
        "would delete. Nothing was deleted",
    ):
        run(out, "--fresh", settings=root / "settings")
    assert (home / "keep.txt").exists() and (work / "keep.txt").exists() and not stages.commands


def test_fresh_deletes_a_folder_the_pipeline_made_and_runs_again(root, stages):
    run("out")
    assert owner(root / "out") == CREATED_BY
    (root / "out" / "stale.txt").write_text("from the earlier run")
    run("out", "--fresh")
    assert not (root / "out" / "stale.txt").exists() and (root / "out" / MARKER).exists()
    assert len(stages.commands) == 8  # every stage twice


@pytest.mark.parametrize("spelling", ["link", "out/sub/.."])
def test_the_lock_is_one_per_folder_however_it_is_spelled(root, stages, spelling):
    out = root / "out"
    claim_output_folder(out, CREATED_BY)
    (out / "sub").mkdir()
    (root / "link").symlink_to(out)
    running = r"Another pipeline \(pid \d+\) is running on " + re.escape(str(out))
    with exclusive(out), pytest.raises(SystemExit, match=running):
        run(spelling)
    assert not stages.commands


def test_a_second_run_spelling_the_folders_another_way_skips_every_stage(root, stages, capsys, monkeypatch):
    run("out")
    assert len(stages.commands) == 4  # record, base, synthesis, recovery
    (root / "link").symlink_to(root / "out")
    for out, settings in ((root / "out", root / "settings"), ("link", "settings/../settings")):
        capsys.readouterr()
        run(out, settings=settings)
        assert capsys.readouterr().out.count("done already") == 4
    # From another checkout (a worktree holding the same settings), the output folder named by its path.
    shutil.copytree(root / "settings", root / "worktree" / "settings")
    monkeypatch.chdir(root / "worktree")
    capsys.readouterr()
    run(root / "out")
    assert capsys.readouterr().out.count("done already") == 4
    assert len(stages.commands) == 4


def test_the_lock_file_goes_with_its_run_completed_or_failed(root, stages):
    run("out")
    assert not (root / ".out.pipeline.lock").exists()
    stages.exit_code = 1
    with pytest.raises(SystemExit, match=f"{TASK} record failed"):
        run("out", "--fresh")
    assert not (root / ".out.pipeline.lock").exists()


def test_a_killed_runs_lock_file_does_not_stop_the_next_run(root, stages):
    (root / ".out.pipeline.lock").write_text("12345")  # kill -9 runs no cleanup; the kernel released its lock
    run("out")
    assert len(stages.commands) == 4 and not (root / ".out.pipeline.lock").exists()


def test_a_users_file_named_as_the_lock_file_is_left_alone(root, stages):
    (root / ".out.pipeline.lock").write_text("my notes")
    with pytest.raises(
        SystemExit, match=r"holds something other than a pipeline's pid: lerobot_ccdp did not"
    ):
        run("out")
    assert (root / ".out.pipeline.lock").read_text() == "my notes" and not stages.commands


def test_a_lock_file_removed_between_opening_and_locking_it_is_not_held(root, monkeypatch):
    """A run that opened the lock file just before the run holding it ended (and removed it) must not hold a
    lock on the removed file while a third run locks the new one: it locks the file the path names now."""
    lock, out = root / ".out.pipeline.lock", root / "out"
    lock.write_text("12345")
    flock, replaced = fcntl.flock, []

    def flock_after_the_file_was_replaced(handle, operation: int) -> None:
        if not replaced:  # the holder removes the file this handle opened; a third run makes a new one
            lock.unlink()
            lock.touch()
            replaced.append(lock.stat().st_ino)
        flock(handle, operation)

    monkeypatch.setattr(run_lock.fcntl, "flock", flock_after_the_file_was_replaced)
    with exclusive(out):
        assert lock.stat().st_ino == replaced[0]
        with pytest.raises(PipelineRunning), exclusive(out):
            pass
    assert not lock.exists()


def test_a_stage_clears_only_inside_its_task_folder(root):
    files = TaskFiles.locate(TASK, root / "settings" / "configs", root / "settings" / "recipes", root / "out")
    mine = user_folder(root / "mine")
    with pytest.raises(PipelineError, match=re.escape(f"refusing to clear {mine}, which is not inside")):
        TaskRun(files)._stage("record", mine / "done", ["lerobot-ccdp-record"], upstream=None, clear=mine)
    assert untouched(mine)


def refusal(capsys, out: str | Path, *extra: str, train_only: bool = False) -> str:
    """The one line the pipeline exits with on `out` and `extra` (sys.exit's message, or argparse's last)."""
    with pytest.raises(SystemExit) as refused:
        run(out, *extra, train_only=train_only)
    code = refused.value.code
    return code if isinstance(code, str) else capsys.readouterr().err.strip().splitlines()[-1]


def everything(folder: Path) -> list[str]:
    """Every path under `folder`, symlinks not followed (one of them loops)."""
    return sorted(os.path.join(d, name) for d, dirs, files in os.walk(folder) for name in dirs + files)


# Inputs refused before any output is touched (issue 110): (--out, flags, what the one line says)
BAD_INPUTS = {
    "an unknown task": (
        "out",
        ["--tasks", "DoorOpening-lite-v9"],
        r"Unknown task 'DoorOpening-lite-v9'; choose among .*DoorOpening-lite-v0",
    ),
    "--configs without the task's folder": (
        "out",
        ["--configs", "empty"],
        rf"{TASK}: missing settings file\(s\) .*empty/{SLUG}/train_base.json",
    ),
    "--out under a file": (
        "notes.txt/out",
        [],
        r"--out .*/notes.txt/out cannot be made: .*/notes.txt is a file",
    ),
    "--out through a symlink loop": ("loop/out", [], r"argument --out: loop/out: a symlink in it loops"),
    "--out in an unknown user's home": (
        "~nosuchuser/out",
        [],
        r"argument --out: ~nosuchuser/out: there is no user nosuchuser",
    ),
    "a negative --eval-seed": ("out", ["--eval-seed", "-1"], r"--eval-seed -1: .*seeds -1 to "),
    "an --eval-seed past numpy's range": (
        "out",
        ["--eval-seed", str(2**40)],
        rf"--eval-seed {2**40}: .*numpy's seed range.*choose a first seed from 0 to ",
    ),
    "episodes that run past numpy's range": (
        "out",
        ["--eval-seed", str(2**32 - 5), "--eval-episodes", "10"],
        r"seeds 4294967291 to 4294967300, outside numpy's seed range.*a first seed from 0 to 4294967286",
    ),
    # suggested "a first seed from 0 to -95705032704"
    "more episodes than numpy has seeds": (
        "out",
        ["--eval-episodes", str(10**11)],
        rf"--eval-episodes {10**11}: more episodes than numpy has seeds .*evaluate at most {2**32}$",
    ),
    # a task or method named twice ran its stages twice, with --jobs two evaluations in one folder at once
    "a task named twice": ("out", ["--tasks", TASK, TASK], rf"--tasks names {TASK} more than once"),
    "a method named twice": ("out", ["--methods", "dp", "ccdp", "dp"], r"--methods names dp more than once"),
    # its run file and chart were copied onto the run's own (shutil.SameFileError after the whole run), or
    # the run file onto its summary.json
    **{
        f"--publish onto the run's {name}": (
            "out",
            ["--publish", f"out/{stem}.md"],
            rf"--publish out/{stem}.md would publish onto out/{name}, a file the pipeline writes there",
        )
        for stem, name in (
            ("episodes", "episodes.json"),
            ("comparison", "comparison.png"),
            ("summary", "summary.json"),
        )
    },
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_a_bad_input_is_one_line_before_any_output_is_touched(root, stages, capsys, case):
    out, extra, message = BAD_INPUTS[case]
    (root / "notes.txt").write_text("keep me")
    (root / "empty").mkdir()
    (root / "loop").symlink_to("loop")
    before = everything(root)
    assert re.search(message, refusal(capsys, out, *extra))
    assert everything(root) == before and not stages.commands


# Settings files that failed only when the stage reading them ran (the recovery section after training the
# base, minutes in), or with a raw TypeError or a JSON error naming no file: (file, old, new, the one line)
BAD_SETTINGS = {
    "a NaN in the recovery recipe": (
        f"recipes/{SLUG}.yaml",
        "sigma: 0.02",
        "sigma: .nan",
        rf"recipes/{SLUG}.yaml: recovery.sigma must be a finite number",
    ),
    "a quoted number in the record recipe": (
        f"recipes/{SLUG}.yaml",
        "n_episodes: 100",
        'n_episodes: "100"',
        r"record.n_episodes must be int, got '100' \(str\)",
    ),
    "an eval config that is not JSON": (
        f"configs/{SLUG}/eval.json",
        '"seed": 2000',
        '"seed": 2000,,',
        rf"configs/{SLUG}/eval.json is not valid JSON: ",
    ),
    "a NaN eval seed": (
        f"configs/{SLUG}/eval.json",
        '"seed": 2000',
        '"seed": NaN',
        rf"configs/{SLUG}/eval.json: seed must be an integer >= 0, got nan",
    ),
    "a quoted eval seed": (f"configs/{SLUG}/eval.json", '"seed": 2000', '"seed": "2000"', r"got '2000'"),
    "no episodes to evaluate": (
        f"configs/{SLUG}/eval.json",
        '"n_episodes": 100',
        '"n_episodes": 0',
        r"eval.n_episodes must be an integer >= 1, got 0",
    ),
}


@pytest.mark.parametrize("case", list(BAD_SETTINGS))
def test_a_bad_settings_file_is_one_line_before_any_output_is_touched(root, stages, capsys, case):
    name, old, new, message = BAD_SETTINGS[case]
    path = root / "settings" / name
    assert old in path.read_text()
    path.write_text(path.read_text().replace(old, new))
    assert re.search(message, refusal(capsys, "out"))
    assert not (root / "out").exists() and not stages.commands


def test_a_bad_eval_seed_loses_no_finished_evaluation(root, stages, capsys):
    """The evaluation stage cleared its finished output before lerobot-eval refused the seed."""
    run("out")
    finished = root / "out" / SLUG / "eval" / "dp" / "eval_info.json"
    finished.parent.mkdir(parents=True)
    finished.write_text("finished")
    for seed in ("-1", str(2**40)):
        assert "--eval-seed" in refusal(capsys, "out", "--methods", "dp", "--eval-seed", seed)
    assert finished.read_text() == "finished" and len(stages.commands) == 4


# Where each publishing flag writes the task's report: (the flag's value, the report's path less .md)
PUBLISH = {"--publish": ("pub/r.md", "pub/r"), "--publish-each": ("pub", f"pub/{TASK}")}


@pytest.mark.parametrize("flag", list(PUBLISH))
@pytest.mark.parametrize("suffix", [".md", ".json", ".png"])
def test_publishing_is_refused_before_any_stage_where_it_would_replace_a_users_file(
    root, stages, capsys, flag, suffix
):
    value, stem = PUBLISH[flag]
    mine = root / f"{stem}{suffix}"
    mine.parent.mkdir()
    mine.write_bytes(b"mine")
    message = refusal(capsys, "out", flag, value)
    named = re.escape(f"{stem}{suffix}")  # as the flag spells it (here, relative to the working directory)
    assert re.search(
        rf"Refusing {flag} .*: {named} .*lerobot_ccdp did not write it\. Nothing was written\. Choose "
        rf"another {flag}, or move or delete {named} yourself",
        message,
    )
    assert mine.read_bytes() == b"mine" and not stages.commands and not (root / "out").exists()


def test_publish_replaces_what_the_pipeline_published_and_refuses_what_appeared_since(root):
    """Checked again when the report is published (a run takes hours). What the pipeline published is
    replaced: docs/benchmark's files (their chart named by their report), a chart it marked."""
    docs, out, pub = REPO / "docs" / "benchmark", root / "out", root / "pub"
    out.mkdir()
    pub.mkdir()
    shutil.copy(docs / "DoorOpening-v0.json", out / RUN_FILE)
    run = results.Run.load(out / RUN_FILE)
    bar_chart(
        {t: {m: MethodMetrics.of(e) for m, e in ms.items()} for t, ms in run.episodes.items()}, pub / "x.png"
    )
    shutil.copy(pub / "x.png", out / "comparison.png")
    for suffix in (".md", ".json", ".png"):
        shutil.copy(docs / f"DoorOpening-v0{suffix}", pub)
    for target in (pub / "DoorOpening-v0.md", pub / "x.md"):
        publish_report("# report\n\n![comparison](comparison.png)\n", out, target)
        assert target.read_text().startswith(REPORT_NOTE)
        assert target.read_text().endswith(f"![comparison]({target.stem}.png)\n")
        assert target.with_suffix(".json").read_bytes() == (out / RUN_FILE).read_bytes()
    (pub / "x.json").write_text("{}")  # a user's file, put there during the run
    before = {p.name: p.read_bytes() for p in pub.iterdir()}
    with pytest.raises(NotOwned, match=re.escape(f"{pub / 'x.json'} is not a run file of the pipeline")):
        publish_report("# another\n", out, pub / "x.md")
    assert {p.name: p.read_bytes() for p in pub.iterdir()} == before


def test_results_never_replace_a_users_file(root, capsys):
    """`python -m lerobot_ccdp.benchmark.results --out`: replaced only where it wrote the file before."""
    run_file = str(REPO / "docs" / "benchmark" / "DoorOpening-v0.json")
    mine = root / "results.md"
    mine.write_text("# my notes")
    with pytest.raises(SystemExit, match=rf"Refusing --out {mine}: .*did not write it\. Nothing was written"):
        results.main(["--run", "Labels", run_file, "--out", str(mine)])
    assert mine.read_text() == "# my notes"
    shutil.copy(REPO / "docs" / "results.md", mine)
    results.main(["--run", "Labels", run_file, "--out", str(mine)])
    assert "| DoorOpening |" in mine.read_text()


class SideBySide(FakeStages):
    """Fake stages that count how many commands run at once; with `wait`, the synthesis waits until a
    baseline's evaluation has started (or 20 s), so a run that evaluates the baselines only after the recovery
    stage shows as none side by side."""

    def __init__(self, wait: bool) -> None:
        super().__init__()
        self.wait = wait
        self.running, self.most, self.threads = 0, 0, set()
        self.lock, self.baseline_started = threading.Lock(), threading.Event()

    def __call__(self, command: list[str], log: Path, label: str, threads: int | None = None) -> int:
        with self.lock:
            self.running += 1
            self.most = max(self.most, self.running)
            self.threads.add(threads)
        name = Path(command[0]).name
        if name == "lerobot-eval" and "--policy.recovery_mode=dp" in command:
            self.baseline_started.set()
        if name == "lerobot-ccdp-synthesize" and self.wait:
            self.baseline_started.wait(timeout=20)
        time.sleep(0.05)
        with self.lock:
            self.running -= 1
        return super().__call__(command, log, label, threads)


OUTPUTS["lerobot-eval"] = ("--output_dir", "eval_info.json")


@pytest.mark.parametrize("jobs", [1, 2])
def test_baselines_are_evaluated_on_the_base_beside_the_recovery_stage(root, monkeypatch, jobs):
    fake = SideBySide(wait=jobs > 1)
    monkeypatch.setattr(pipeline, "run_with_progress", fake)
    monkeypatch.setattr(TaskRun, "episodes", lambda self, methods: {})
    files = TaskFiles.locate(TASK, Path("settings/configs"), Path("settings/recipes"), root / "out")
    TaskRun(files, jobs=jobs).run(["dp", "dp_star", "ccdp"])
    policy = {
        next(a for a in c if a.startswith("--output_dir=")).split("/")[-1]: next(
            a.split("=", 1)[1] for a in c if a.startswith("--policy.path=")
        )
        for c in fake.commands
        if Path(c[0]).name == "lerobot-eval" and "--env.render_mode=null" in c
    }
    assert policy == {
        "dp": str(files.out / "base" / CHECKPOINT),
        "dp_star": str(files.out / "base" / CHECKPOINT),
        "ccdp": str(files.out / "recovery" / CHECKPOINT),
    }
    assert fake.most == jobs  # side by side with 2 jobs, never more commands at once than jobs
    assert fake.threads == {pipeline.stage_threads(jobs)}


def test_a_training_seed_reaches_both_trainings_and_the_synthesis_and_reruns_them(root, stages):
    """`--train-seed S` (issue 114's trainings 0 / 1 / 2): both lerobot-train stages get `--seed=S` and the
    synthesis `--recovery.seed=S`; the recording does not (the data are the task's); without it no command
    names a seed, so a run of the configs' own seeds keeps its stamps."""
    run("out")
    assert not any(a.startswith(("--seed=", "--recovery.seed=")) for c in stages.commands for a in c)
    stages.commands.clear()
    run("out", "--train-seed", "2")
    seeded = [(Path(c[0]).name, [a for a in c if "seed=" in a]) for c in stages.commands]
    # the recording is reused (the data are the task's), everything after it trained again
    assert seeded == [
        ("lerobot-train", ["--seed=2"]),
        ("lerobot-ccdp-synthesize", ["--recovery.seed=2"]),
        ("lerobot-train", ["--seed=2"]),
    ]


def flag(command: list[str], name: str) -> str:
    """The value of `name`=... in `command`."""
    return next(arg.split("=", 1)[1] for arg in command if arg.startswith(f"{name}="))


def test_the_eps_z_column_trains_its_own_heads_from_the_same_base_and_evaluates_them_as_ccdp(
    root, stages, monkeypatch, capsys
):
    """`ccdp_eps_z` (issue 114's fifth column, eq. (4) with the eps_z heads): on a task whose own head is the
    set denoiser, a synthesis and a recovery stage of its own from the same base with
    `--policy.recovery_head=unet` (the recipe's siblings and the base config's set-denoiser settings, which
    the eps_z heads refuse, off), into folders of its own, and an evaluation that differs from CCDP's only in
    the checkpoint and the output folder (same seeds, noise streams and sampling). Each stage resumes on its
    own; `--train-only` trains the heads of the methods named."""
    monkeypatch.setattr(TaskRun, "episodes", lambda self, methods: {})
    configs, recipe = root / "settings" / "configs" / SLUG, root / "settings" / "recipes" / f"{SLUG}.yaml"
    base_config = json.loads((configs / "train_base.json").read_text())
    base_config["policy"].update(recovery_head="set_denoiser", stratum_weights=True)
    (configs / "train_base.json").write_text(json.dumps(base_config))
    recipe.write_text(recipe.read_text().replace("recovery:\n", "recovery:\n  demo_siblings: true\n"))
    claim_output_folder(root / "out", CREATED_BY)  # as main does, for its --train-only run below
    files = TaskFiles.locate(TASK, Path("settings/configs"), Path("settings/recipes"), root / "out")
    TaskRun(files).run(["dp", "ccdp", "ccdp_eps_z"])
    by_output = {Path(flag(c, OUTPUTS[Path(c[0]).name][0])): c for c in stages.commands}
    out, base = files.out, str(files.out / "base" / CHECKPOINT)
    synthesis, eps_z_synthesis = by_output[out / "recovery_data"], by_output[out / "recovery_data_eps_z"]
    assert flag(eps_z_synthesis, "--policy.path") == flag(synthesis, "--policy.path") == base
    assert [a for a in eps_z_synthesis if a not in synthesis] == [
        "--policy.recovery_head=unet",
        "--recovery.demo_siblings=false",
        f"--output.repo_id=local/{SLUG}_recovery_eps_z",
        f"--output.root={out / 'recovery_data_eps_z'}",
    ]
    training, eps_z_training = by_output[out / "recovery"], by_output[out / "recovery_eps_z"]
    assert flag(eps_z_training, "--policy.path") == flag(training, "--policy.path") == base
    assert (
        flag(eps_z_training, "--config_path") == flag(training, "--config_path") == str(files.train_recovery)
    )
    assert "--policy.training_stage=recovery" in eps_z_training
    assert [a for a in eps_z_training if a not in training] == [
        f"--dataset.repo_id=local/{SLUG}_recovery_eps_z",
        f"--dataset.root={out / 'recovery_data_eps_z'}",
        f"--output_dir={out / 'recovery_eps_z'}",
        "--policy.recovery_head=unet",
        "--policy.stratum_weights=false",
    ]
    ccdp, eps_z = by_output[out / "eval" / "ccdp"], by_output[out / "eval" / "ccdp_eps_z"]
    assert flag(eps_z, "--policy.path") == str(out / "recovery_eps_z" / CHECKPOINT)
    assert flag(ccdp, "--policy.path") == str(out / "recovery" / CHECKPOINT)
    assert [(a, b) for a, b in zip(eps_z, ccdp, strict=True) if a != b] == [
        (
            f"--policy.path={out / 'recovery_eps_z' / CHECKPOINT}",
            f"--policy.path={out / 'recovery' / CHECKPOINT}",
        ),
        (f"--output_dir={out / 'eval' / 'ccdp_eps_z'}", f"--output_dir={out / 'eval' / 'ccdp'}"),
    ]
    assert {"synthesize_eps_z", "train_recovery_eps_z", "eval_ccdp_eps_z"} <= set(
        json.loads((out / "stamps.json").read_text())
    )
    # resumed: nothing again; the eps_z heads gone, their training alone again (from the same inputs, so the
    # evaluation stands); the column's own methods.json setting, its evaluation alone again
    stages.commands.clear()
    TaskRun(files).run(["dp", "ccdp", "ccdp_eps_z"])
    assert not stages.commands
    shutil.rmtree(out / "recovery_eps_z")
    TaskRun(files).run(["dp", "ccdp", "ccdp_eps_z"])
    (configs / "methods.json").write_text(json.dumps({"ccdp_eps_z": {"w_z": 3}}))
    TaskRun(files).run(["dp", "ccdp", "ccdp_eps_z"])
    assert [Path(flag(c, "--output_dir")) for c in stages.commands] == [
        out / "recovery_eps_z",
        out / "eval" / "ccdp_eps_z",
    ]
    assert "--policy.w_z=3" in stages.commands[-1]
    # --train-only trains the eps_z heads where --methods names them, and names both heads
    shutil.rmtree(out / "recovery_eps_z")
    stages.commands.clear()
    capsys.readouterr()
    run(root / "out", "--methods", "ccdp", "ccdp_eps_z")
    assert [Path(flag(c, "--output_dir")) for c in stages.commands] == [out / "recovery_eps_z"]
    heads = (out / "recovery" / CHECKPOINT, out / "recovery_eps_z" / CHECKPOINT)
    assert f"Trained: {heads[0]}, {heads[1]}" in capsys.readouterr().out
