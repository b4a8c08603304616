"""Loading a checkpoint never reads a dataset: lerobot-record hands make_policy the metadata of a new, empty
recording dataset, which has no label column; the outcome table must come from the checkpoint. Weights that do
not fit are refused, not left at random values."""

import json
import logging
import shutil
from pathlib import Path

import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.policies.factory import make_policy
from safetensors.torch import load_file, save_file

from lerobot_ccdp.policy.checkpoint_files import without_retired_fields
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

from fixtures.policy_factory import untrained_checkpoint
from fixtures.reaching import REACHING_REPO_ID

OUTCOME_TABLE = ("model.outcomes.chunks", "model.outcomes.final_states", "model.outcomes.primitives")


def recording_meta(demo_root, root) -> LeRobotDatasetMetadata:
    """What lerobot-record passes: a new dataset with the robot's features only (no `primitive` label)."""
    demos = LeRobotDatasetMetadata(REACHING_REPO_ID, root=demo_root)
    features = {k: v for k, v in demos.features.items() if k != "primitive"}
    return LeRobotDatasetMetadata.create(
        "local/recording", fps=demos.fps, features=features, root=root, use_videos=False
    )


def test_make_policy_with_a_recording_datasets_meta_loads_the_saved_outcome_table(
    untrained_primitive_checkpoint, reaching_root, tmp_path
):
    config = PreTrainedConfig.from_pretrained(untrained_primitive_checkpoint)
    config.pretrained_path = untrained_primitive_checkpoint  # what --policy.path sets
    policy = make_policy(config, ds_meta=recording_meta(reaching_root, tmp_path / "recording"))
    saved = load_file(untrained_primitive_checkpoint / "model.safetensors")
    assert len(policy.model.outcomes) > 0
    for key in OUTCOME_TABLE:
        torch.testing.assert_close(policy.state_dict()[key], saved[key])


def test_from_pretrained_ignores_dataset_arguments(untrained_primitive_checkpoint, reaching_root, tmp_path):
    meta = recording_meta(reaching_root, tmp_path / "recording")
    policy = CCDPPolicy.from_pretrained(
        untrained_primitive_checkpoint, dataset_meta=meta, dataset_stats=meta.stats
    )
    saved = load_file(untrained_primitive_checkpoint / "model.safetensors")
    torch.testing.assert_close(policy.model.outcomes.primitives, saved["model.outcomes.primitives"])


def test_a_fresh_base_stage_still_builds_its_table_and_names_a_missing_label_column(reaching_root, tmp_path):
    config = PreTrainedConfig.from_pretrained(
        untrained_checkpoint(reaching_root, tmp_path / "ckpt", failure_feature="primitive", num_primitives=4)
    )
    config.input_features = {}
    fresh = make_policy(config, ds_meta=LeRobotDatasetMetadata(REACHING_REPO_ID, root=reaching_root))
    assert len(fresh.model.outcomes) > 0
    with pytest.raises(ValueError, match="lacks column.*primitive"):
        make_policy(config, ds_meta=recording_meta(reaching_root, tmp_path / "recording"))


def test_weights_that_do_not_fit_are_refused_with_the_fix(untrained_primitive_checkpoint, tmp_path):
    """A checkpoint from before the policy/model split keeps its networks at the top level (`base.*`, not
    `model.base.*`): LeRobot's non-strict default would load nothing and act with random weights."""
    old = tmp_path / "old_layout"
    shutil.copytree(untrained_primitive_checkpoint, old)
    weights = load_file(old / "model.safetensors")
    save_file(
        {key.removeprefix("model."): value for key, value in weights.items()}, old / "model.safetensors"
    )
    expected = (
        r"do not fit the ccdp policy its config describes: \d+ missing \(model\.base\..*"
        r"unexpected \(base\..*retrain"
    )
    with pytest.raises(ValueError, match=expected):
        CCDPPolicy.from_pretrained(old)


def test_a_set_denoiser_base_starts_the_eps_z_heads_recovery_stage_and_a_trained_head_still_must_fit(
    reaching_root, tmp_path
):
    """`lerobot-train --policy.path=<set-denoiser base> --policy.training_stage=recovery
    --policy.recovery_head=unet` (the benchmark's eq. (4) column beside the task's own head) loads the base's
    networks and outcome table, and the eps_z heads at their own initialisation: the base's untrained set
    denoiser has tensors of the same names and other shapes, which torch refused. A trained head of another
    shape is still refused with the fix."""
    settings = {"failure_feature": "primitive", "num_primitives": 4, "history_length": 0}
    base = untrained_checkpoint(reaching_root, tmp_path / "base", recovery_head="set_denoiser", **settings)
    config = PreTrainedConfig.from_pretrained(
        base, cli_overrides=["--recovery_head=unet", "--training_stage=recovery"]
    )
    config.pretrained_path = base  # what --policy.path sets
    policy = make_policy(config, ds_meta=LeRobotDatasetMetadata(REACHING_REPO_ID, root=reaching_root))
    saved, loaded = load_file(base / "model.safetensors"), policy.state_dict()
    assert policy.config.recovery_head == "unet" and not bool(policy.model.recovery_trained)
    shared = [k for k in saved if not k.startswith("model.recovery.")]
    assert all(torch.equal(loaded[k], saved[k]) for k in shared) and OUTCOME_TABLE[0] in shared
    film = "model.recovery.unet.down_modules.0.0.cond_encoder.1.weight"  # conditioned on z, not on F
    assert loaded[film].shape != saved[film].shape
    trained = shutil.copytree(base, tmp_path / "trained")
    save_file({**saved, "model.recovery_trained": torch.tensor(True)}, trained / "model.safetensors")
    config.pretrained_path = trained
    with pytest.raises(ValueError, match=rf"{film} has shape .*, the config makes"):
        make_policy(config, ds_meta=LeRobotDatasetMetadata(REACHING_REPO_ID, root=reaching_root))


# ----- a checkpoint saved before settings were removed from CCDPConfig (issue 112) -------------------------

# What every config.json saved before the removal holds: each removed field at the value the policy now fixes.
OLD_LAYOUT = {
    "w_s": 1.0,
    "w_z_from_step": 0,
    "z_reference": "eps_z_null",
    "failure_state_key": "observation.state",
    "failure_action_steps": [],
    "failure_action_dims": [],
    "ccdp_redraws": 0,
}


def saved_with(checkpoint: Path, tmp_path: Path, **fields) -> Path:
    """A copy of `checkpoint` whose config.json also says `fields`, as one saved before they were removed."""
    copy = shutil.copytree(checkpoint, tmp_path / "old")
    config = json.loads((copy / "config.json").read_text())
    (copy / "config.json").write_text(json.dumps({**config, **fields}))
    return copy


def test_a_checkpoint_saved_with_the_removed_settings_loads_and_says_so(
    untrained_primitive_checkpoint, tmp_path, caplog
):
    """lerobot-eval's and lerobot-train's route (`PreTrainedConfig.from_pretrained` with --policy.* flags) and
    the Python API's both read it; draccus refused every removed field ("The fields `w_s`, ... are not valid
    for CCDPConfig")."""
    folder = saved_with(untrained_primitive_checkpoint, tmp_path, **OLD_LAYOUT)
    with caplog.at_level(logging.WARNING):
        config = PreTrainedConfig.from_pretrained(folder, cli_overrides=["--recovery_mode=dp_star"])
    assert config.recovery_mode == "dp_star"
    assert f"dropped the retired setting(s) {', '.join(OLD_LAYOUT)}, at the values" in caplog.text
    policy = CCDPPolicy.from_pretrained(folder)
    assert policy.model.weights.w_s == 1.0 and policy.model.weights.z_reference == "eps_z_null"


def test_a_removed_setting_that_would_sample_otherwise_is_refused_by_name(
    untrained_primitive_checkpoint, tmp_path
):
    folder = saved_with(
        untrained_primitive_checkpoint, tmp_path, **{**OLD_LAYOUT, "w_s": 0.5, "ccdp_redraws": 3}
    )
    message = (
        r"config\.json sets w_s=0\.5, which CCDP no longer offers \(eq\. \(4\)'s state weight is 1\); "
        r"ccdp_redraws=3, which CCDP no longer offers \(CCDP draws one sample per plan\)\. Evaluate the "
        r"checkpoint with the lerobot_ccdp release that trained it, or remove w_s, ccdp_redraws from its "
        r"config\.json"
    )
    with pytest.raises(ValueError, match=message):
        PreTrainedConfig.from_pretrained(folder)
    with pytest.raises(ValueError, match=message):
        CCDPPolicy.from_pretrained(folder)


def test_an_environment_state_z_becomes_the_same_dims_of_the_state_frame():
    saved = {
        "type": "ccdp",
        "input_features": {
            "observation.state": {"shape": [4]},
            "observation.environment_state": {"shape": [3]},
        },
        "failure_state_key": "observation.environment_state",
        "failure_state_dims": [0, 2],
    }
    assert without_retired_fields(saved, "config.json")["failure_state_dims"] == [4, 6]
    every = without_retired_fields({**saved, "failure_state_dims": []}, "config.json")
    assert every["failure_state_dims"] == [4, 5, 6]
