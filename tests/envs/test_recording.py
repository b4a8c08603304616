"""Recipes and `lerobot-ccdp-record`: a loadable state-only LeRobot dataset, written atomically."""

from pathlib import Path

import numpy as np
import pytest
import yaml
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_ccdp.datasets import record
from lerobot_ccdp.datasets.recipe_file import RecordRecipe
from lerobot_ccdp.envs import TASKS

RECIPES = Path(__file__).parents[2] / "datasets_recipes"


def _write(tmp_path: Path, content: dict) -> Path:
    path = tmp_path / "recipe.yaml"
    path.write_text(yaml.safe_dump(content))
    return path


def test_every_task_has_a_recipe():
    # reaching2d.yaml holds only a `recovery:` section: its demos come from `python -m
    # lerobot_ccdp.benchmark.reaching2d`.
    recorded = [p for p in RECIPES.glob("*.yaml") if "record" in yaml.safe_load(p.read_text())]
    assert {RecordRecipe.load(p).task for p in recorded} == set(TASKS)
    assert len(recorded) == len(list(RECIPES.glob("*.yaml"))) - 1


@pytest.mark.parametrize("task", list(TASKS))
def test_recorded_dataset_loads_with_labels(task, tmp_path):
    root = tmp_path / "demos"
    recipe = RecordRecipe(task=task, n_episodes=3, seed=5)
    record.record_dataset(recipe, "local/test", root, progress=False)
    dataset = LeRobotDataset("local/test", root=root)
    assert dataset.num_episodes == 3 and dataset.fps == 10
    assert {
        "observation.state",
        "observation.environment_state",
        "action",
        "primitive",
        "hidden_param",
    } <= set(dataset.features)
    assert not any("image" in k or "failure" in k for k in dataset.features)
    assert dataset.meta.video_keys == []
    frames = dataset.hf_dataset.with_format("numpy")[:]
    n_options = TASKS[task].n_options
    assert set(np.unique(frames["primitive"])) <= set(range(n_options))
    for ep in range(3):
        hidden = frames["hidden_param"][frames["episode_index"] == ep]
        assert len(np.unique(hidden)) == 1  # one hidden parameter per episode
    assert yaml.safe_load((root / record.RECIPE_COPY).read_text())["record"]["task"] == task
    assert list(tmp_path.iterdir()) == [root]  # no staging folder left behind


def test_crash_leaves_nothing_half_written(tmp_path, monkeypatch):
    calls = []

    def crash_on_third(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    real = record.run_episode
    monkeypatch.setattr(record, "run_episode", crash_on_third)
    with pytest.raises(KeyboardInterrupt):
        record.record_dataset(
            RecordRecipe(task="ButtonSearch-lite-v0", n_episodes=5, seed=0), "local/x", tmp_path / "ds"
        )
    assert list(tmp_path.iterdir()) == []


def test_recipe_ignores_other_sections_and_names_problems(tmp_path):
    recipe = RecordRecipe.load(
        _write(
            tmp_path,
            {"record": {"task": "Bartender-lite-v0", "n_episodes": 4, "seed": 1}, "recovery": {"sigma": 0.1}},
        )
    )
    assert recipe == RecordRecipe(task="Bartender-lite-v0", n_episodes=4, seed=1)
    with pytest.raises(ValueError, match="missing required field.*seed"):
        RecordRecipe.load(_write(tmp_path, {"record": {"task": "Bartender-lite-v0", "n_episodes": 4}}))
    with pytest.raises(ValueError, match="unknown field.*n_epsiodes"):
        RecordRecipe.load(
            _write(tmp_path, {"record": {"task": "Bartender-lite-v0", "n_epsiodes": 4, "seed": 0}})
        )
    with pytest.raises(ValueError, match="known tasks: DoorOpening-v0"):
        RecordRecipe.load(_write(tmp_path, {"record": {"task": "Bar-v0", "n_episodes": 4, "seed": 0}}))
    with pytest.raises(ValueError, match="no top-level `record:` section"):
        RecordRecipe.load(_write(tmp_path, {"recovery": {}}))
    with pytest.raises(ValueError, match="n_episodes must be a positive integer"):
        RecordRecipe.load(
            _write(tmp_path, {"record": {"task": "Bartender-lite-v0", "n_episodes": 0, "seed": 0}})
        )


@pytest.mark.parametrize(
    "field, value, expected",
    [
        ("seed", "zero", "record.seed must be int, got 'zero'"),
        ("n_episodes", True, "record.n_episodes must be int, got True"),
        ("fps", "10", "record.fps must be int, got '10'"),
        ("max_episode_steps", 2.5, r"record.max_episode_steps must be int \| None"),
    ],
)
def test_recipe_fields_of_the_wrong_type_are_named(tmp_path, field, value, expected):
    content = {"task": "Bartender-lite-v0", "n_episodes": 4, "seed": 0, field: value}
    with pytest.raises(ValueError, match=expected):
        RecordRecipe.load(_write(tmp_path, {"record": content}))


def test_recipe_yaml_errors_name_the_file(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("record:\n  task: [DoorOpening-lite-v0\n")
    with pytest.raises(ValueError, match=f"Recipe {path} is not valid YAML"):
        RecordRecipe.load(path)


def test_overwrite_replaces_only_a_dataset(tmp_path, monkeypatch):
    recipe = RecordRecipe(task="DoorOpening-lite-v0", n_episodes=1, seed=0)
    notes = tmp_path / "mydir" / "notes.txt"
    notes.parent.mkdir()
    notes.write_text("keep me")
    with pytest.raises(
        ValueError, match=r"only replaces a dataset that lerobot_ccdp wrote .*nothing was deleted"
    ):
        record.record_dataset(recipe, "local/x", notes.parent, overwrite=True, progress=False)
    monkeypatch.chdir(notes.parent)
    for root in (Path("."), tmp_path):  # the working directory, and a folder holding it
        with pytest.raises(ValueError, match="holds the working directory"):
            record.record_dataset(recipe, "local/x", root, overwrite=True, progress=False)
    assert notes.read_text() == "keep me" and sorted(p.name for p in tmp_path.iterdir()) == ["mydir"]


def test_a_killed_runs_staging_folder_is_removed_by_the_next_run(tmp_path):
    root = tmp_path / "ds"
    stale = tmp_path / f".ds.{2**22 + 7}.abc.partial"  # a pid above Linux's pid_max: no such process
    (stale / "dataset").mkdir(parents=True)
    record.record_dataset(
        RecordRecipe(task="DoorOpening-lite-v0", n_episodes=1, seed=0), "local/x", root, progress=False
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
