"""Dataset writing never deletes or damages what lerobot_ccdp did not create (issue 49), and says why not.

Each test drives the commands as a user would: `record.main`, `synthesize.main`, the console script."""

import errno
import json
import os
import re
import resource
import shutil
import subprocess
from pathlib import Path

import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_ccdp.benchmark import reaching2d
from lerobot_ccdp.datasets import record
from lerobot_ccdp.datasets.ownership import MARKER, identity, owner
from lerobot_ccdp.datasets.staging import CREATED_BY
from lerobot_ccdp.recovery import synthesize

from fixtures.policy_factory import untrained_checkpoint
from fixtures.reaching import BIN, REACHING_REPO_ID

TASK = "DoorOpening-lite-v0"
DEMOS_ID = "local/door"
RECOVERY = [
    "--recovery.n_states=4",
    "--recovery.chunks_per_state=2",
    "--recovery.demo_frames=32",
]


def record_flags(root: Path, *extra: str, n_episodes: int = 1) -> list[str]:
    return [
        f"--record.task={TASK}",
        f"--record.n_episodes={n_episodes}",
        "--record.seed=0",
        f"--dataset.repo_id={DEMOS_ID}",
        f"--dataset.root={root}",
        *extra,
    ]


def synthesize_flags(demos: Path, checkpoint: Path, output: Path | str, *extra: str) -> list[str]:
    return [
        *RECOVERY,
        f"--dataset.repo_id={DEMOS_ID}",
        f"--dataset.root={demos}",
        f"--policy.path={checkpoint}",
        "--output.repo_id=local/recovery",
        f"--output.root={output}",
        *extra,
    ]


def listing(folder: Path) -> dict[str, int]:
    """Every file under `folder` with its size: what must survive a refused command unchanged."""
    return {str(p.relative_to(folder)): p.stat().st_size for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def door(tmp_path_factory) -> tuple[Path, Path]:
    """Demos recorded by lerobot-ccdp-record (so lerobot_ccdp owns them), an untrained checkpoint of them."""
    demos = tmp_path_factory.mktemp("door") / "demos"
    record.main(record_flags(demos, n_episodes=2))
    return demos, untrained_checkpoint(demos, demos.parent / "base", DEMOS_ID, failure_feature="action")


def symlink(link: Path, target: Path) -> Path:
    link.symlink_to(target, target_is_directory=True)
    return link


# Output roots that are, hold or lie inside an input: (demos, checkpoint, tmp_path) -> --output.root.
OVERLAPS = {
    "the demos": lambda demos, base, tmp: str(demos),
    "the demos through a symlink": lambda demos, base, tmp: str(symlink(tmp / "link", demos)),
    "the demos through ..": lambda demos, base, tmp: str(demos / "meta" / ".."),
    "the demos relative to the working directory": lambda demos, base, tmp: os.path.relpath(demos),
    "a folder inside the demos": lambda demos, base, tmp: str(demos / "recovery"),
    "a folder holding the demos": lambda demos, base, tmp: str(demos.parent),
    "a folder inside the checkpoint": lambda demos, base, tmp: str(base / "recovery"),
}


@pytest.mark.parametrize("case", list(OVERLAPS))
def test_synthesis_refuses_an_output_that_overlaps_an_input(door, tmp_path, case):
    demos, checkpoint = door
    output = OVERLAPS[case](demos, checkpoint, tmp_path)
    before = listing(demos.parent)
    flag = "--policy.path" if "checkpoint" in case else "--dataset.root"
    with pytest.raises(ValueError, match=rf"--output.root={re.escape(output)} .*{flag}=.*nothing was done"):
        synthesize.main(synthesize_flags(demos, checkpoint, output, "--overwrite=true"))
    assert listing(demos.parent) == before and LeRobotDataset(DEMOS_ID, root=demos).num_episodes == 2


def test_overwrite_refuses_a_folder_that_only_looks_like_a_dataset(tmp_path):
    fake = tmp_path / "mine"
    (fake / "meta").mkdir(parents=True)
    (fake / "meta" / "info.json").write_text("{}")
    (fake / "thesis.tex").write_text("years of work")
    with pytest.raises(SystemExit, match=rf"{fake} is not one, so nothing was deleted. Choose a new root"):
        record.main(record_flags(fake, "--overwrite=true"))
    assert listing(fake) == {"meta/info.json": 2, "thesis.tex": 13}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"], "no staging folder left"


def test_overwrite_replaces_only_the_dataset_it_wrote_at_that_same_path(tmp_path):
    """A copy, a moved dataset or a symlink to one carry a marker, but not one of their own path."""
    original, copy, moved = tmp_path / "original", tmp_path / "copy", tmp_path / "moved"
    record.main(record_flags(original))
    shutil.copytree(original, copy)
    record.main(record_flags(tmp_path / "to_move"))
    (tmp_path / "to_move").rename(moved)
    (tmp_path / "link").symlink_to(original, target_is_directory=True)
    for root in (copy, moved, tmp_path / "link"):
        before = listing(root)
        with pytest.raises(SystemExit, match="nothing was deleted"):
            record.main(record_flags(root, "--overwrite=true", n_episodes=2))
        assert listing(root) == before
    record.main(record_flags(original, "--overwrite=true", n_episodes=2))
    assert LeRobotDataset(DEMOS_ID, root=original).num_episodes == 2
    marker = json.loads((original / MARKER).read_text())
    assert marker == {"created_by": "lerobot_ccdp dataset", "path_sha256": identity(original.resolve())}
    # pushed to the Hub with the data: no local path
    assert str(tmp_path) not in (original / MARKER).read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["copy", "link", "moved", "original"]


def test_a_run_removes_only_its_own_roots_dead_staging_folders(tmp_path):
    """`data` and `data.v2` share a prefix; writing `data` leaves every staging folder of `data.v2` alone and
    those of `data` that a live process still writes."""
    dead = 2**22 + 7  # above Linux's pid_max: no such process
    kept = [
        f".data.v2.{os.getpid()}.k3y_9ab1.partial",
        f".data.v2.{dead}.zz81ab_c.partial",
        f".data.{os.getpid()}.live0123.partial",
        ".data.notapid.abc.partial",
        f".data.{dead}.{os.getpid()}.abcd1234.partial",  # the last: a live one of root `data.4194311`
    ]
    for name in [*kept, f".data.{dead}.x1y2z3_w.partial"]:
        (tmp_path / name / "dataset").mkdir(parents=True)
    record.main(record_flags(tmp_path / "data"))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*kept, "data"])


def test_a_root_under_a_file_is_refused_before_recording(tmp_path, monkeypatch):
    (tmp_path / "notes.txt").write_text("keep me")
    monkeypatch.setattr(record, "run_episode", lambda *args, **kwargs: pytest.fail("recorded first"))
    root = tmp_path / "notes.txt" / "demos"
    with pytest.raises(SystemExit, match=rf"Cannot create the dataset {root}: .*notes.txt is a file"):
        record.main(record_flags(root))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_parent_is_refused_before_recording(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    with pytest.raises(SystemExit, match=rf"the dataset {locked}/sub/demos: {locked} is not writable"):
        record.main(record_flags(locked / "sub" / "demos"))
    assert list(locked.iterdir()) == []


@pytest.mark.parametrize("where", ["staging", "elsewhere"])
def test_a_write_failure_names_the_dataset_and_leaves_nothing(tmp_path, monkeypatch, where):
    """A permission error on a file of the dataset is reported by the dataset's name, not the staging
    folder's; one on a file elsewhere (a device, an input) is not the dataset's to explain, and passes."""

    def denied(dataset, *args):
        path = dataset.root / "data" if where == "staging" else Path("/dev/dri/renderD128")
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))

    monkeypatch.setattr(record, "_add_episode", denied)
    with pytest.raises(PermissionError) as error:
        record.main(record_flags(tmp_path / "demos"))
    if where == "staging":
        message = error.value.strerror
        assert message.startswith(f"Permission denied in {tmp_path} while writing demos: nothing was written")
        assert ".partial" not in message and "folder you can write to" in message
    else:
        assert error.value.filename == "/dev/dri/renderD128"
    assert list(tmp_path.iterdir()) == []


def test_a_file_size_limit_is_named_by_the_console_script(tmp_path):
    """RLIMIT_FSIZE (`ulimit -f`) makes a dataset file fail with EFBIG midway; the command's last word names
    the dataset and the limit, and leaves neither the dataset nor its staging folder."""

    def limit_file_size() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (16 * 1024, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))

    result = subprocess.run(
        [str(BIN / "lerobot-ccdp-record"), *record_flags(tmp_path / "demos")],
        capture_output=True,
        text=True,
        preexec_fn=limit_file_size,
        env={**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"},
    )
    last = result.stderr.strip().splitlines()[-1]
    assert result.returncode != 0
    assert last.startswith(f"OSError: [Errno {errno.EFBIG}] File too large in {tmp_path} while writing demos")
    assert "ulimit -f" in last and ".partial" not in last
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "flag, message",
    [
        (
            "--record.env_kwargs={obs_typ: pixels_agent_pos}",
            rf"record.env_kwargs: {TASK} takes no argument.* obs_typ; it accepts .*, obs_type, ",
        ),
        ("--record.max_episode_steps=0", "record.max_episode_steps must be a positive integer, got 0"),
        ("--record.max_episode_steps=-5", "record.max_episode_steps must be a positive integer, got -5"),
        ("--record.env_kwargs={init_noise: .nan}", "record.env_kwargs.init_noise must be a finite number"),
        ("--record.seed=-1", r"record.seed must be >= 0 \(gymnasium's seeds\), got -1"),
        # YAML reads 1e9 as text, which the env compared with numbers in numpy's words (issue 110)
        (
            "--record.env_kwargs={init_noise: 1e9}",
            r"record.env_kwargs.init_noise must be float, got '1e9' \(str\); write it without quotes",
        ),
        ("--record.env_kwargs={render_width: 2.5}", "record.env_kwargs.render_width must be int, got 2.5"),
        # gymnasium wrapped the env in a pygame window, and the run died at exit in EGL's teardown
        ("--record.env_kwargs={render_mode: human}", "record.env_kwargs.render_mode='human': the recorder "),
        # recorded, then refused by the training that read it
        (
            "--dataset.repo_id=my demos",
            "--dataset.repo_id='my demos' is not a repo id: .* Write namespace/name",
        ),
        ("--dataset.repo_id=", "--dataset.repo_id='' is not a repo id"),
    ],
)
def test_record_recipe_errors_are_named_before_any_env_is_made(tmp_path, monkeypatch, flag, message):
    monkeypatch.setattr(record.gym, "make", lambda *args, **kwargs: pytest.fail("an env was made"))
    with pytest.raises(SystemExit, match=rf"lerobot-ccdp-record: error: {message}"):
        record.main(record_flags(tmp_path / "demos", flag))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("field", ["sigma", "delta_z", "delta_x", "outcome_radius"])
@pytest.mark.parametrize("value", [".nan", ".inf"])
def test_a_recovery_recipe_refuses_non_finite_numbers(tmp_path, field, value):
    """From the recipe file or a flag, before any path is looked at."""
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(f"recovery:\n  {field}: {value}\n")
    flags = synthesize_flags(tmp_path / "demos", tmp_path / "base", tmp_path / "out")
    from_file = [f"--config_path={recipe}", *(f for f in flags if not f.startswith("--recovery."))]
    for args in (from_file, [*flags, f"--recovery.{field}={value}"]):
        with pytest.raises(SystemExit, match=rf"synthesize: error: recovery.{field} must be a finite number"):
            synthesize.main(args)


def test_a_checkpoint_of_another_layout_is_refused_naming_both(door, reaching_root, tmp_path):
    demos, _ = door
    other = untrained_checkpoint(
        reaching_root, tmp_path / "reaching_base", REACHING_REPO_ID, failure_feature="action"
    )
    features = LeRobotDataset(DEMOS_ID, root=demos).meta.features
    state, action = features["observation.state"]["shape"][0], features["action"]["shape"][0]
    expected = (
        rf"checkpoint expects observation.state \(2,\), action \(2,\); dataset {DEMOS_ID} has "
        rf"observation.state \({state},\), action \({action},\)"
    )
    with pytest.raises(ValueError, match=expected):
        synthesize.main(synthesize_flags(demos, other, tmp_path / "out"))
    assert list(tmp_path.iterdir()) == [tmp_path / "reaching_base"]


def test_a_step_limit_too_short_for_the_expert_is_named_with_the_tasks_own(tmp_path):
    with pytest.raises(
        SystemExit,
        match=r"^lerobot-ccdp-record: error: The DoorOpening-lite-v0 expert failed 2 times; giving up\. "
        r"Every failed episode ran to its step limit of 3 steps \(record.max_episode_steps\).*raise "
        r"--record.max_episode_steps \(the task's own limit: 150\) or "
        r"leave it unset",
    ):
        record.main(record_flags(tmp_path / "demos", "--record.max_episode_steps=3"))
    assert list(tmp_path.iterdir()) == []


def test_a_dangling_symlink_root_is_named_as_one(tmp_path):
    link = tmp_path / "demos"
    link.symlink_to(tmp_path / "gone")
    with pytest.raises(
        SystemExit, match=rf"error: {link} is a symlink to {tmp_path / 'gone'}, which does not exist"
    ):
        record.main(record_flags(link))
    assert link.is_symlink() and sorted(p.name for p in tmp_path.iterdir()) == ["demos"]


def test_an_empty_folder_root_receives_the_dataset(tmp_path):
    root = tmp_path / "demos"
    root.mkdir()
    record.main(record_flags(root))
    assert LeRobotDataset(DEMOS_ID, root=root).num_episodes == 1 and owner(root) == CREATED_BY
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demos"]


def test_the_reaching_data_command_names_an_existing_root(tmp_path, capsys):
    """`python -m lerobot_ccdp.benchmark.reaching2d --root R` run twice: the second says what to do."""
    root = tmp_path / "reaching2d"
    flags = ["--root", str(root), "--n-episodes", "4"]
    reaching2d.main(flags)
    with pytest.raises(SystemExit):
        reaching2d.main(flags)
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.endswith(f"{root} already exists; pass --overwrite to replace it, or choose another root")
    reaching2d.main(["--root", str(root), "--n-episodes", "10", "--overwrite"])
    assert LeRobotDataset("local/reaching2d", root=root).num_episodes == 10 and owner(root) == CREATED_BY


@pytest.mark.parametrize("spelling", ["", ".", ".."])
@pytest.mark.parametrize("overwrite", [[], ["--overwrite=true"]])
def test_a_root_spelling_the_working_directory_is_refused_with_or_without_overwrite(
    tmp_path, monkeypatch, spelling, overwrite
):
    """An empty --dataset.root is the working directory: it was reported as "already exists; pass
    --overwrite=true", which would then be refused too (issue 110)."""
    work = tmp_path / "work"
    work.mkdir()
    (work / "notes.txt").write_text("keep me")
    monkeypatch.chdir(work)
    with pytest.raises(
        SystemExit,
        match=r"^lerobot-ccdp-record: error: The dataset root \.{1,2} is or holds the working directory, "
        r"which the dataset would replace\. Name the dataset's own folder",
    ):
        record.main(record_flags(Path(spelling), *overwrite))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["work"] and listing(work) == {"notes.txt": 7}


def test_a_users_file_as_root_is_refused_without_offering_overwrite(tmp_path):
    """--overwrite=true would be refused on it as well, so the first refusal says so."""
    mine = tmp_path / "notes.txt"
    mine.write_text("keep me")
    with pytest.raises(SystemExit) as refused:
        record.main(record_flags(mine))
    assert str(refused.value.code) == (
        f"lerobot-ccdp-record: error: {mine} already exists and is not a dataset lerobot_ccdp wrote at this "
        f"same path (marked by {MARKER}), so --overwrite=true would not replace it either. Choose a new "
        "root, or move or remove it yourself if it is yours to lose."
    )
    assert mine.read_text() == "keep me"


def test_an_env_setting_out_of_range_is_one_line(tmp_path):
    with pytest.raises(
        SystemExit,
        match=r"^lerobot-ccdp-record: error: record.env_kwargs: \{'max_failures': 0\}: the attempt budget .* "
        r"must be >= 1",
    ):
        record.main(record_flags(tmp_path / "demos", "--record.env_kwargs={max_failures: 0}"))
    assert list(tmp_path.iterdir()) == []
