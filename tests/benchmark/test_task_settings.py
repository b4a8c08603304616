"""The shipped settings files as the pipeline finds them: every task has its state settings, and each camera variant
(`configs/<task>_pixels/`, `datasets_recipes/<task>_pixels.yaml`) is its state twin with only the camera fields
changed, so a setting tuned on the state task cannot silently drift from its pixel copy."""

import importlib.util
import json
from pathlib import Path

import pytest
import yaml

from lerobot_ccdp.benchmark.pipeline import TaskFiles, task_slug
from lerobot_ccdp.datasets.recipe_file import RecoveryRecipe
from lerobot_ccdp.envs import TASKS
from lerobot_ccdp.policy.configuration_ccdp import FAILURE_STATES_AT, CCDPConfig

REPO = Path(__file__).resolve().parents[2]
CONFIGS, RECIPES = REPO / "configs", REPO / "datasets_recipes"
PIXEL_TASKS = [t for t in TASKS if (CONFIGS / f"{task_slug(t)}_pixels").is_dir()]


def _without(config: dict, *paths: str) -> dict:
    """`config` without the dotted `paths`, which the camera variant sets differently."""
    config = json.loads(json.dumps(config))
    for path in paths:
        *parents, key = path.split(".")
        node = config
        for parent in parents:
            node = node[parent]
        node.pop(key, None)
    return config


@pytest.mark.parametrize("task", TASKS)
def test_every_task_has_its_state_settings(task, tmp_path):
    files = TaskFiles.locate(task, CONFIGS, RECIPES, tmp_path)
    assert yaml.safe_load(files.recipe.read_text())["record"]["task"] == task


def test_the_physics_door_and_buttons_have_camera_variants():
    assert {"DoorOpening-v0", "ButtonSearch-v0", "DoorOpening-lite-v0", "ButtonSearch-lite-v0"} <= set(PIXEL_TASKS)


@pytest.mark.parametrize("task", PIXEL_TASKS)
def test_a_camera_variant_is_its_state_twin_with_only_the_camera_fields_changed(task, tmp_path):
    state = TaskFiles.locate(task, CONFIGS, RECIPES, tmp_path)
    pixels = TaskFiles.locate(task, CONFIGS, RECIPES, tmp_path, "pixels_agent_pos")
    slug = task_slug(task) + "_pixels"

    base = json.loads(pixels.train_base.read_text())
    assert base["dataset"] == {"repo_id": f"local/{slug}", "root": f"data/{slug}", "video_backend": "pyav"}
    assert base["output_dir"] == f"outputs/{slug}/train_base"
    assert base["policy"]["history_length"] == 0  # the camera encoder sees the current frames only
    camera_fields = ("dataset", "output_dir", "policy.history_length", "policy.vision_backbone_stages")
    assert _without(base, *camera_fields) == _without(json.loads(state.train_base.read_text()), *camera_fields)

    recovery = json.loads(pixels.train_recovery.read_text())
    assert recovery["dataset"]["repo_id"] == f"local/{slug}_recovery"
    assert _without(recovery, "dataset", "output_dir") == _without(
        json.loads(state.train_recovery.read_text()), "dataset", "output_dir")

    evaluation = pixels.eval_config()
    assert evaluation["env"]["obs_type"] == "pixels_agent_pos"
    assert _without(evaluation, "env.obs_type", "eval.batch_size") == _without(state.eval_config(), "eval.batch_size")

    recipe, state_recipe = (yaml.safe_load(f.read_text()) for f in (pixels.recipe, state.recipe))
    assert recipe["record"].pop("env_kwargs") == {"obs_type": "pixels_agent_pos"}
    assert recipe == state_recipe


def test_label_free_inputs_define_z_alike_in_the_recipe_and_the_policy_and_change_nothing_else(tmp_path):
    """benchmarks/label_free_inputs.py: the synthesis stage refuses a recipe whose z differs from the base
    checkpoint's, and every file it does not edit must stay the benchmark's own."""
    spec = importlib.util.spec_from_file_location("label_free_inputs", REPO / "benchmarks" / "label_free_inputs.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    label_free = script.TASKS

    script.write_inputs(tmp_path)
    for task in TASKS:
        slug = task_slug(task)
        files = TaskFiles.locate(task, tmp_path / "configs", tmp_path / "recipes", tmp_path / "out")
        shipped = TaskFiles.locate(task, CONFIGS, RECIPES, tmp_path / "out")
        if slug not in label_free:
            assert files.train_base.read_bytes() == shipped.train_base.read_bytes()
            assert files.recipe.read_bytes() == shipped.recipe.read_bytes()
            continue
        policy = json.loads(files.train_base.read_text())["policy"]
        wanted = RecoveryRecipe.load(files.recipe).failure_settings()
        assert wanted["failure_feature"] == "final_state"
        assert {k: policy.get(k, CCDPConfig.failure_state_key) for k in wanted} == wanted  # the key: its default
        assert "num_primitives" not in policy
        assert policy.get("failure_segments", CCDPConfig.failure_segments) == label_free[slug].segments
        for method in ("dp_star", "ccdp"):
            settings = files.method_settings(method)
            assert settings["failure_state_at"] in FAILURE_STATES_AT
            delta_z = label_free[slug].eval_delta_z
            assert settings.get("delta_z", CCDPConfig.delta_z) == (CCDPConfig.delta_z if delta_z is None else delta_z)
        w_z = shipped.method_settings("ccdp").get("w_z") if label_free[slug].w_z is None else label_free[slug].w_z
        assert files.method_settings("ccdp").get("w_z") == w_z  # the label-free runs' own weight where it differs
        assert files.train_recovery.read_bytes() == shipped.train_recovery.read_bytes()
