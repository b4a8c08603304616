"""The pipeline writes into and deletes only output folders it made (issue 49): `--fresh` on a user's folder,
the working directory or the home folder deletes nothing, and an output folder is one folder however it is
spelled, for its lock and its stage stamps. The stages are faked (each makes the output its stage checks for),
so these run in seconds; tests/benchmark/test_pipeline.py runs the real ones."""

import fcntl
import re
import shutil
from pathlib import Path

import pytest

from lerobot_ccdp.benchmark import pipeline, run_lock
from lerobot_ccdp.benchmark.pipeline import (
    CHECKPOINT,
    CREATED_BY,
    PipelineError,
    TaskFiles,
    TaskRun,
    main,
    task_slug,
)
from lerobot_ccdp.benchmark.run_lock import PipelineRunning, exclusive
from lerobot_ccdp.datasets.ownership import MARKER, claim_output_folder, owner

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


def run(out: str | Path, *extra: str, settings: str | Path = "settings") -> None:
    """The pipeline's training stages on `out`, the settings spelled from `settings`."""
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
            "--train-only",
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
