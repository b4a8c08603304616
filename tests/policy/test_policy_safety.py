"""Adversarial inputs to the policy, as a careful user and a hostile checkpoint author would try them.

A checkpoint never makes the policy delete or watch a file; every non-finite setting, input, z and batch is
refused where it enters; a training that cannot work is refused before its first step; a config error is the
last line of a LeRobot command's output (issue "Nothing a user types destroys data"). The NaN observation was
refused before; every other test here failed (or, for the short dataset, hung) before that issue's change.
"""

import json
import logging
import os
import shutil
import subprocess

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
from lerobot.policies.factory import make_policy as lerobot_make_policy

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

from fixtures.policy_factory import make_policy
from fixtures.reaching import BIN, REACHING_REPO_ID, train_args

STATE = {"observation.state": torch.zeros(1, 2)}


def _crafted(checkpoint, tmp_path, **fields):
    """A copy of `checkpoint` whose config.json says `fields`, as a hostile author would publish it."""
    crafted = tmp_path / "crafted"
    crafted.mkdir()
    for file in checkpoint.iterdir():
        (crafted / file.name).write_bytes(file.read_bytes())
    config = json.loads((crafted / "config.json").read_text())
    (crafted / "config.json").write_text(json.dumps({**config, **fields}))
    return crafted


def _load_as_lerobot_does(checkpoint, reaching_root, *cli_overrides):
    """lerobot-eval / lerobot-record: the config with the command line's overrides, then LeRobot's
    make_policy."""
    config = PreTrainedConfig.from_pretrained(checkpoint, cli_overrides=list(cli_overrides))
    config.pretrained_path = checkpoint
    return lerobot_make_policy(config, ds_meta=LeRobotDatasetMetadata(REACHING_REPO_ID, root=reaching_root))


# ----- a checkpoint cannot name a file ----------------------------------------------------------------------


def test_a_checkpoint_naming_a_signal_file_neither_deletes_nor_watches_it(
    untrained_primitive_checkpoint, reaching_root, tmp_path, caplog
):
    victim = tmp_path / "thesis.tex"
    victim.write_text("years of work")
    crafted = _crafted(untrained_primitive_checkpoint, tmp_path, failure_signal_file=str(victim))
    with caplog.at_level(logging.WARNING, logger="lerobot_ccdp.policy.checkpoint_files"):
        for policy in (CCDPPolicy.from_pretrained(crafted), _load_as_lerobot_does(crafted, reaching_root)):
            assert policy.failure_signal is None and policy.config.failure_signal_file is None
    assert victim.read_text() == "years of work"
    assert any("cannot choose a file" in r.getMessage() for r in caplog.records)


def test_the_signal_file_comes_from_the_command_line_and_is_never_saved(
    untrained_primitive_checkpoint, reaching_root, tmp_path
):
    signal = tmp_path / "ccdp_failed"
    policy = _load_as_lerobot_does(
        untrained_primitive_checkpoint, reaching_root, f"--failure_signal_file={signal}"
    )
    assert policy.failure_signal is not None and policy.failure_signal.path == signal
    policy.save_pretrained(tmp_path / "saved")
    assert json.loads((tmp_path / "saved" / "config.json").read_text())["failure_signal_file"] is None
    # saving leaves the running policy's setting alone
    assert policy.config.failure_signal_file == str(signal)


# ----- the signal file: read, never deleted -----------------------------------------------------------------


def test_an_existing_signal_file_with_content_is_kept_and_is_no_failure(tmp_path):
    signal = tmp_path / "notes.txt"
    signal.write_text("my notes")
    os.utime(signal, ns=(0, 0))
    policy = make_policy(failure_signal_file=str(signal))
    policy.select_action(STATE)
    policy.select_action(STATE)
    assert policy.failure_count().tolist() == [0] and signal.read_text() == "my notes"
    signal.touch()  # a detector's touch is one failure; the file stays
    policy.select_action(STATE)
    assert policy.failure_count().tolist() == [1] and signal.read_text() == "my notes"
    os.utime(signal, ns=(1, 1))  # and each touch after it another
    policy.select_action(STATE)
    assert policy.failure_count().tolist() == [2]


def test_a_signal_path_that_is_a_folder_is_refused_at_load(tmp_path):
    with pytest.raises(ValueError, match="plain file"):
        make_policy(failure_signal_file=str(tmp_path))


def test_a_signal_file_that_becomes_a_folder_mid_episode_warns_once_and_acts_on(tmp_path, caplog):
    signal = tmp_path / "ccdp_failed"
    policy = make_policy(failure_signal_file=str(signal))
    policy.select_action(STATE)
    signal.mkdir()
    with caplog.at_level(logging.WARNING, logger="lerobot_ccdp.policy.failure_signal"):
        for _ in range(3):
            assert policy.select_action(STATE).shape == (1, 2)
    assert len([r for r in caplog.records if "cannot be read" in r.getMessage()]) == 1
    assert policy.failure_count().tolist() == [0]


# ----- non-finite numbers -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["w_z", "w_h", "delta_z", "optimizer_lr", "crop_ratio"])
@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_a_non_finite_setting_is_refused_naming_it(name, value):
    with pytest.raises(ValueError, match=f"`{name}` must be a finite number"):
        CCDPConfig(**{name: value})


@pytest.mark.parametrize("name", ["n_action_steps", "n_obs_steps", "horizon", "num_inference_steps"])
def test_a_chunk_size_of_zero_is_refused(name):
    with pytest.raises(ValueError, match=f"`{name}`.*>= 1"):
        CCDPConfig(**{name: 0})


@pytest.mark.parametrize(
    "overrides,message",
    [
        ({"delta_z": -0.1}, "`delta_z`"),
        ({"down_dims": ()}, "`down_dims`"),
        ({"kernel_size": 0}, "`kernel_size`"),
        ({"dp_star_candidates": 0}, "`dp_star_candidates`"),
        ({"scheduler_warmup_steps": -5}, "`scheduler_warmup_steps`"),
        ({"num_train_timesteps": 5, "num_inference_steps": 10}, "cannot exceed `num_train_timesteps`"),
    ],
)
def test_a_size_that_would_fail_later_is_refused_at_once(overrides, message):
    """Each of these built a policy that failed at construction, at the first sample or after training."""
    with pytest.raises(ValueError, match=message):
        CCDPConfig(**overrides)


def test_an_observation_without_its_batch_dimension_is_refused_with_the_fix():
    with pytest.raises(ValueError, match=r"unsqueeze\(0\)"):
        make_policy().select_action({"observation.state": torch.zeros(2)})


def test_integer_observations_and_a_list_z_are_taken_as_numbers():
    policy = make_policy()
    assert policy.select_action({"observation.state": torch.zeros(1, 2, dtype=torch.long)}).shape == (1, 2)
    policy.report_failure(rows=[0], z=[0.0] * policy.config.failure_feature_dim)
    assert policy.failure_count().tolist() == [1]


def test_a_non_finite_observation_is_refused_before_acting():
    policy = make_policy()
    with pytest.raises(ValueError, match="'observation.state' contains NaN or inf"):
        policy.select_action({"observation.state": torch.tensor([[float("nan"), 0.0]])})


def test_a_non_finite_batch_stops_training_naming_the_key():
    policy = make_policy().train()
    batch = {"observation.state": torch.zeros(4, 1, 2), "action": torch.zeros(4, 16, 2)}
    batch["action"][2, 5, 1] = float("inf")
    with pytest.raises(ValueError, match=r"NaN or inf in \['action'\]"):
        policy.forward(batch)


def test_report_failure_refuses_a_non_finite_z():
    policy = make_policy()
    policy.select_action(STATE)
    with pytest.raises(ValueError, match="NaN or inf"):
        policy.report_failure(rows=[0], z=torch.full((1, policy.config.failure_feature_dim), float("nan")))
    assert policy.failure_count().tolist() == [0]


def test_report_failure_refuses_negative_rows_and_takes_an_empty_list_as_no_failure():
    policy = make_policy()
    policy.select_action({"observation.state": torch.zeros(3, 2)})
    with pytest.raises(ValueError, match=r"indices 0\.\.2"):
        policy.report_failure(rows=[-1])
    policy.report_failure(rows=[])
    assert policy.failure_count().tolist() == [0, 0, 0]


# ----- trainings that cannot work, refused before the first step --------------------------------------------


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(BIN / args[0]), *args[1:]],
        capture_output=True,
        text=True,
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )


@pytest.mark.slow  # a lerobot-train process (about 20 s on the slower machine)
def test_lerobot_train_refuses_a_dataset_shorter_than_a_chunk(reaching_root, tmp_path):
    """Its 32-frame episodes leave no window for a 48-step chunk: lerobot-train used to wait for a batch
    forever."""
    result = _run(
        *train_args(reaching_root, tmp_path / "out", 10, "--policy.horizon=48", "--policy.n_action_steps=1")
    )
    assert result.returncode != 0
    assert "no frame to train on" in result.stderr.strip().splitlines()[-1]


def test_lerobot_train_stops_on_nan_actions_its_stats_do_not_show(reaching_root, tmp_path):
    """stats.json computed before the data went bad: LeRobot would train on to a NaN checkpoint and exit 0.
    The outcome table, which reads every frame, now names the first bad one before the first step."""
    root = tmp_path / "damaged"
    shutil.copytree(reaching_root, root)
    for file in (root / "data").rglob("*.parquet"):
        table = pq.read_table(file)
        actions = np.stack(table.column("action").to_numpy(zero_copy_only=False)).astype(np.float32)
        actions[::2] = np.nan  # every other frame: the first batch holds some
        column = pa.FixedSizeListArray.from_arrays(pa.array(actions.ravel()), actions.shape[1])
        pq.write_table(table.set_column(table.schema.get_field_index("action"), "action", column), file)
    result = _run(*train_args(root, tmp_path / "out", 5))
    assert result.returncode != 0
    assert "holds NaN or inf in column 'action' at episode 0, frame 0 (" in result.stderr
    assert not (tmp_path / "out" / "checkpoints").exists()


def test_the_recovery_stage_without_a_base_is_refused_as_lerobot_train_builds_it(reaching_root):
    """lerobot-train without --policy.path: LeRobot's make_policy builds a fresh policy for the dataset."""
    config = CCDPConfig(
        training_stage="recovery", failure_feature="primitive", num_primitives=4, device="cpu"
    )
    with pytest.raises(ValueError, match=r"--policy.path=<base run>/checkpoints"):
        lerobot_make_policy(config, ds_meta=LeRobotDatasetMetadata(REACHING_REPO_ID, root=reaching_root))


@pytest.mark.slow  # a lerobot-train process (about 20 s on the slower machine)
def test_a_config_error_is_the_last_line_of_lerobot_train(reaching_root, tmp_path):
    result = _run(*train_args(reaching_root, tmp_path / "out", 10, "--policy.w_z=nan"))
    assert result.returncode != 0
    assert result.stderr.strip().splitlines()[-1].startswith("ValueError: `w_z` must be a finite number")


# ----- a checkpoint of another kind -------------------------------------------------------------------------


def test_a_checkpoint_of_another_action_size_names_both_layouts(untrained_primitive_checkpoint):
    config = PreTrainedConfig.from_pretrained(untrained_primitive_checkpoint)
    # what make_policy sets from an env
    config.output_features = {"action": PolicyFeature(FeatureType.ACTION, (7,))}
    with pytest.raises(ValueError, match=r"action \(2,\).*action \(7,\)"):
        CCDPPolicy.from_pretrained(untrained_primitive_checkpoint, config=config)


def test_a_diffusion_checkpoint_is_refused_by_name(tmp_path):
    config = DiffusionConfig(
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (2,)),
            "observation.environment_state": PolicyFeature(FeatureType.ENV, (2,)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
        device="cpu",
        down_dims=(8, 16),
        horizon=16,
    )
    DiffusionPolicy(config).save_pretrained(tmp_path / "diffusion")
    with pytest.raises(ValueError, match="'diffusion' checkpoint, not a ccdp one"):
        CCDPPolicy.from_pretrained(tmp_path / "diffusion")
