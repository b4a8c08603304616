"""What this project's commands delete or write into is a folder they made where it is (issue 49): a user's
folder, a copy or a symlink of ours is refused, and the benchmark scripts that clear their folders follow the
same rule."""

from pathlib import Path

import pytest

from lerobot_ccdp.benchmark import tune_methods
from lerobot_ccdp.datasets.ownership import MARKER, NotOwned, claim_output_folder, identity, mark, owner


def users_folder(path: Path) -> Path:
    path.mkdir()
    (path / "thesis.tex").write_text("years of work")
    return path


def test_a_marker_holds_only_where_it_was_written(tmp_path, monkeypatch):
    ours = tmp_path / "ours"
    ours.mkdir()
    mark(ours, "a command")
    (tmp_path / "x").mkdir()
    monkeypatch.chdir(tmp_path)
    assert owner(ours) == owner(Path("ours")) == owner(tmp_path / "x" / ".." / "ours") == "a command"
    (tmp_path / "link").symlink_to(ours)
    (tmp_path / "copy").mkdir()
    (tmp_path / "copy" / MARKER).write_bytes((ours / MARKER).read_bytes())
    assert owner(tmp_path / "link") is None and owner(tmp_path / "copy") is None
    assert str(tmp_path) not in (ours / MARKER).read_text() and identity(ours) in (ours / MARKER).read_text()


def test_another_commands_folder_is_not_claimed(tmp_path):
    folder = tmp_path / "out"
    claim_output_folder(folder, "one command")
    (folder / "result.json").write_text("{}")
    with pytest.raises(NotOwned, match="made by one command, not by another"):
        claim_output_folder(folder, "another", fresh=True)
    assert (folder / "result.json").exists()


def test_tune_methods_writes_only_into_a_pipeline_output_folder(tmp_path):
    mine = users_folder(tmp_path / "mine")
    with pytest.raises(SystemExit, match="not an output folder of the pipeline.*--adopt"):
        tune_methods.main(["--out", str(mine), "--tasks", "DoorOpening-lite-v0"])
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.tex"]
