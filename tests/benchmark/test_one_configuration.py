"""Issue 114's one configuration: a Panda task's settings folder describes the task and its data, and CCDP's
method settings are `CCDPConfig`'s and `RecoveryRecipe`'s defaults.

A task folder may hold what describes the task and its data (the dataset and output paths, the chunk length,
what z is and where the demos mark an option's end, the training seeds and sizes) and nothing that tunes the
method. Every method setting a folder still sets is listed in OPEN_DEPARTURES, the part of issue 114 not done:
a new one, or one of them changed, fails here, and one folded into the defaults is taken off the list.
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from lerobot_ccdp.benchmark.pipeline import TaskFiles, task_slug
from lerobot_ccdp.benchmark.task_settings import base_steps, method_settings
from lerobot_ccdp.envs import TASKS

REPO = Path(__file__).resolve().parents[2]
CONFIGS, RECIPES = REPO / "configs", REPO / "datasets_recipes"
PANDA = [t for t in TASKS if "lite" not in t]

# Method settings the folders still set, as `file: {field: value}` (methods.json as `method.field`): none
# since the Bartenders' departures were folded in (issue 114; docs/benchmarks.md, "The one configuration").
# The recovery head, the guard, where a failure's label or z is read and its Fourier octaves are
# CCDPConfig's defaults: the set denoiser for these state inputs, its guard on the last 4 reverse steps at
# weight 8, a failure named by the demonstrated chunk nearest the one executing, and 4 octaves for a point
# z.
OPEN_DEPARTURES: dict[str, dict] = {}


@pytest.mark.parametrize("label_free", [False, True], ids=["labelled", "label_free"])
@pytest.mark.parametrize("task", PANDA)
def test_a_task_folder_sets_no_method_setting_but_the_open_departures(task, label_free, tmp_path):
    files = TaskFiles.locate(task, CONFIGS, RECIPES, tmp_path, label_free=label_free)
    slug = task_slug(task) + ("_label_free" if label_free else "")
    assert method_settings(files) == OPEN_DEPARTURES.get(slug, {})


@pytest.mark.parametrize("label_free", [False, True], ids=["labelled", "label_free"])
@pytest.mark.parametrize("task", PANDA)
def test_a_task_folder_gets_the_benchmarked_head_by_default(task, label_free, tmp_path):
    """The set denoiser every table measured, as lerobot-train names it for the task's state inputs."""
    files = TaskFiles.locate(task, CONFIGS, RECIPES, tmp_path, label_free=label_free)
    assert files.recovery_head() == "set_denoiser"


def test_a_method_setting_in_a_task_folder_is_found(tmp_path):
    """The check reads every place a setting can hide: a field of the base's policy, a training file's own
    field, methods.json and the recipe's synthesis fields."""
    files = TaskFiles.locate("DoorOpening-v0", CONFIGS, RECIPES, tmp_path)
    copy = {}
    for name in ("train_base", "train_recovery", "eval"):
        copy[name] = tmp_path / "configs" / "door_opening" / f"{name}.json"
        copy[name].parent.mkdir(parents=True, exist_ok=True)
        copy[name].write_text(getattr(files, name).read_text())
    base = json.loads(copy["train_base"].read_text())
    base["policy"]["w_z"] = 2.0
    copy["train_base"].write_text(json.dumps(base))
    (copy["eval"].parent / "methods.json").write_text(json.dumps({"dp_star": {"dp_star_candidates": 64}}))
    recipe = yaml.safe_load(files.recipe.read_text())
    recipe["recovery"] = {"sigma": 0.05, "failure_feature": "primitive"}
    (tmp_path / "recipes").mkdir()
    (tmp_path / "recipes" / "door_opening.yaml").write_text(yaml.safe_dump(recipe))
    changed = TaskFiles.locate("DoorOpening-v0", tmp_path / "configs", tmp_path / "recipes", tmp_path / "out")
    assert method_settings(changed) == {
        "train_base": {"w_z": 2.0},
        "methods": {"dp_star.dp_star_candidates": 64},
        "recipe": {"sigma": 0.05},
    }


# The recovery head's length: 6000 steps of batch 128 on the default synthesis's rows (about 37000; issue 114,
# docs/benchmarks.md "The set denoiser's rows and training": on the buttons 1152 and 576 steps lost 0.24 and
# 0.27 of success on the development seeds). The folders that still train it otherwise, and why:
HEAD_STEPS, HEAD_BATCH = 6000, 128
OPEN_HEAD_LENGTHS = {
    "door_opening": 600,  # the quickstart in ten minutes (issue 111): its CCDP the same at 500, 1000 and 6000
}


@pytest.mark.parametrize("label_free", [False, True], ids=["labelled", "label_free"])
@pytest.mark.parametrize("task", PANDA)
def test_a_task_folder_trains_the_head_the_rule_s_length_but_the_open_departures(task, label_free, tmp_path):
    files = TaskFiles.locate(task, CONFIGS, RECIPES, tmp_path, label_free=label_free)
    slug = task_slug(task) + ("_label_free" if label_free else "")
    head = json.loads(files.train_recovery.read_text())
    assert (head["steps"], head["batch_size"]) == (OPEN_HEAD_LENGTHS.get(slug, HEAD_STEPS), HEAD_BATCH)
    assert head["save_freq"] == head["steps"]  # the checkpoint evaluated is the last


# The frames each Panda recipe records (lerobot-ccdp-record from its seed; a label-free recipe records its
# labelled twin's episodes), which the base's length rule reads; the slow test below records them again.
DEMO_FRAMES = {
    "door_opening": 2424,
    "object_manipulation": 2571,
    "button_search": 1772,
    "object_packing": 7930,
    "bartender": 5368,
}


# The folders whose base the rule does not give yet, and why (docs/benchmarks.md, "The Bartenders at the one
# configuration"): at the rule's 1600 steps, one configuration, on 1000-1099, the labelled Bartender 0.73 /
# 0.18 and the label-free one 0.76 / 0.15; at 7200 steps 0.99 / 0.06 and 0.95 / 0.10 (the labelled at 2400
# 0.89 / 0.12).
OPEN_BASE_LENGTHS = {"bartender": 7200, "bartender_label_free": 7200}


@pytest.mark.parametrize("label_free", [False, True], ids=["labelled", "label_free"])
@pytest.mark.parametrize("task", PANDA)
def test_a_task_folder_trains_the_base_the_rule_s_length_but_the_open_departures(task, label_free, tmp_path):
    """One written rule for the base's length (`task_settings.base_steps`): at least 19 epochs over the
    demonstrations, in whole 800-step intervals; the checkpoint evaluated is the last."""
    files = TaskFiles.locate(task, CONFIGS, RECIPES, tmp_path, label_free=label_free)
    base = json.loads(files.train_base.read_text())
    slug = task_slug(task) + ("_label_free" if label_free else "")
    rule = base_steps(DEMO_FRAMES[task_slug(task)], base["batch_size"])
    assert base["steps"] == OPEN_BASE_LENGTHS.get(slug, rule)
    assert base["save_freq"] == base["steps"]


@pytest.mark.parametrize("task", PANDA)
def test_a_label_free_recipe_records_its_labelled_twin_s_episodes(task):
    slug = task_slug(task)
    labelled, label_free = (
        yaml.safe_load((RECIPES / f"{name}.yaml").read_text()) for name in (slug, f"{slug}_label_free")
    )
    assert labelled["record"] == label_free["record"]


def test_the_rule_gives_at_least_its_epochs_in_whole_intervals():
    assert [base_steps(frames, 64) for frames in (2424, 1772, 7930, 5368)] == [800, 800, 2400, 1600]
    assert base_steps(2694, 64) == 800 and base_steps(2695, 64) == 1600  # 19 epochs: 799.8, 800.1 steps
    assert base_steps(2424, 32) == 1600


@pytest.mark.slow
@pytest.mark.parametrize("task", PANDA)
def test_the_recipes_record_the_frames_the_rule_reads(task, tmp_path):
    slug = task_slug(task)
    record = Path(sys.executable).parent / "lerobot-ccdp-record"
    command = [str(record), f"--config_path={RECIPES / f'{slug}.yaml'}", f"--dataset.repo_id=local/{slug}"]
    subprocess.run([*command, f"--dataset.root={tmp_path / 'demos'}"], check=True, capture_output=True)
    info = json.loads((tmp_path / "demos" / "meta" / "info.json").read_text())
    assert info["total_frames"] == DEMO_FRAMES[slug]
