"""Loading a checkpoint never reads a dataset: lerobot-record hands make_policy the metadata of a new, empty
recording dataset, which has no label column; the outcome table must come from the checkpoint. Weights that do
not fit are refused, not left at random values."""

import shutil

import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.policies.factory import make_policy
from safetensors.torch import load_file, save_file

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
