"""Bad configuration and bad input give errors that name the problem and the fix."""

import errno
import gc
import os

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_ccdp.datasets.recipe_file import RecordRecipe
from lerobot_ccdp.datasets.record import record_dataset
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

from fixtures.policy_factory import make_policy


@pytest.mark.parametrize(
    "overrides,message",
    [
        ({"w_z": -0.5}, "w_z"),
        ({"recovery_mode": "greedy"}, "recovery_mode"),
        ({"failure_feature": "colour"}, "failure_feature"),
        ({"prediction_type": "sample"}, "epsilon"),
        ({"training_stage": "finetune"}, "training_stage"),
        ({"failure_feature": "primitive"}, "num_primitives"),
        ({"horizon": 12}, "multiple"),
        ({"recovery_head": "mlp"}, "recovery_head"),
        ({"failure_segments": "releases"}, "failure_segments"),
        ({"w_h": 0.5}, "history_length"),
    ],
)
def test_invalid_config_is_rejected(overrides, message):
    with pytest.raises(ValueError, match=message):
        CCDPConfig(**overrides)


def test_failure_state_dims_the_dataset_lacks_are_rejected():
    with pytest.raises(ValueError, match=r"failure_state_dims.*\[5\]"):
        make_policy(failure_feature="final_state", failure_state_dims=[0, 5])


def test_failure_state_dims_reach_the_environment_state_after_the_robots():
    """Dims index the state frame: observation.state's 2 dims, then observation.environment_state's 3."""
    policy = make_policy(env_dim=3, failure_feature="final_state", failure_state_dims=[1, 4])
    frame = torch.arange(5.0)[None]
    assert policy.model.feature.from_frame(frame).tolist() == [[1.0, 4.0]]
    with pytest.raises(ValueError, match=r"failure_state_dims.*\[5\].*5-dim state frame.*0\.\.4"):
        make_policy(env_dim=3, failure_feature="final_state", failure_state_dims=[0, 5])


def test_missing_state_feature_is_rejected_at_construction():
    config = CCDPConfig(
        input_features={"observation.environment_state": PolicyFeature(FeatureType.ENV, (3,))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
        device="cpu",
    )
    with pytest.raises(ValueError, match="observation.state"):
        CCDPPolicy(config)


def test_missing_observation_in_a_batch_names_the_key():
    policy = make_policy()
    with pytest.raises(KeyError, match="observation.state"):
        policy.select_action({"observation.environment_state": torch.zeros(1, 2)})


def test_nan_in_a_training_batch_is_reported():
    policy = make_policy()
    batch = {"observation.state": torch.zeros(4, 1, 2), "action": torch.zeros(4, 16, 2)}
    batch["observation.state"][2, 0, 1] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        policy.forward(batch)


def test_wrong_state_width_is_reported():
    policy = make_policy()
    with pytest.raises(ValueError, match="expects 2"):
        policy.select_action({"observation.state": torch.zeros(1, 3)})


def test_recovery_batch_with_wrong_failure_feature_is_reported():
    policy = make_policy(training_stage="recovery", failure_feature="action")
    batch = {"action": torch.zeros(4, 16, 2), "observation.failure_feature": torch.zeros(4, 7)}
    with pytest.raises(ValueError, match="size 32"):
        policy.forward(batch)
    with pytest.raises(ValueError, match="lerobot-ccdp-synthesize"):
        policy.forward({"action": torch.zeros(4, 16, 2)})


def test_inf_in_an_observation_is_refused_before_it_reaches_the_actions():
    policy = make_policy()
    with pytest.raises(ValueError, match="'observation.state' contains NaN or inf"):
        policy.select_action({"observation.state": torch.tensor([[0.0, float("inf")]])})


def test_a_dataset_with_nan_actions_is_refused_before_training():
    config = make_policy().config
    stats = {
        "observation.state": {"mean": torch.zeros(2), "std": torch.ones(2)},
        "action": {"mean": torch.tensor([0.0, float("nan")]), "std": torch.ones(2)},
    }
    with pytest.raises(ValueError, match=r"mean of 'action' is not finite.*NaN or inf in 'action'"):
        CCDPPolicy(config, dataset_stats=stats)


def test_a_batch_size_change_that_drops_failures_says_so(caplog):
    policy = make_policy()
    policy.select_action({"observation.state": torch.zeros(2, 2)})
    policy.report_failure(rows=[0], z=torch.zeros(1, policy.config.failure_feature_dim))
    with caplog.at_level("WARNING"):
        policy.select_action({"observation.state": torch.zeros(3, 2)})
    assert "from 2 to 3 rows without reset(): the 1 remembered failure(s) are dropped" in caplog.text
    assert policy.failure_count().tolist() == [0, 0, 0]


def fill_the_disk(monkeypatch: pytest.MonkeyPatch, at_open: bool) -> list[int]:
    """Make pyarrow's parquet writers see a disk that fills at the third table written (the second episode's
    frames): that write fails with ENOSPC and later ones with "Operation on closed file"; with `at_open`,
    opening a writer then fails with ENOSPC once its file exists, as a real one does. Returns the count of
    writes, live."""
    write_table, open_writer, writes = pq.ParquetWriter.write_table, pq.ParquetWriter.__init__, [0]

    def write(writer, table, row_group_size=None):
        writes[0] += 1
        if writes[0] < 3:
            return write_table(writer, table, row_group_size)
        if writes[0] == 3:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        raise pa.ArrowInvalid("Operation on closed file")

    def open_(writer, *args, **kwargs):
        open_writer(writer, *args, **kwargs)
        if at_open and writes[0] >= 3:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(pq.ParquetWriter, "write_table", write)
    monkeypatch.setattr(pq.ParquetWriter, "__init__", open_)
    return writes


@pytest.mark.parametrize("at_open", [False, True])
def test_a_full_disk_while_writing_a_dataset_is_named_and_leaves_nothing(tmp_path, monkeypatch, at_open):
    """Neither LeRobot's later "Operation on closed file" nor its own ENOSPC on closing the dataset hides the
    full disk, and no destructor run after the failure writes a new partial folder."""
    writes = fill_the_disk(monkeypatch, at_open)
    out = tmp_path / "out"
    with pytest.raises(
        OSError, match=f"No space left on device in {out} while writing demos.*Free space"
    ) as error:
        record_dataset(
            RecordRecipe(task="DoorOpening-lite-v0", n_episodes=2, seed=0),
            "local/d",
            out / "demos",
            progress=False,
        )
    assert error.value.errno == errno.ENOSPC and writes[0] >= 3
    del error
    gc.collect()
    assert list(out.iterdir()) == [], "no dataset and no .partial staging folder"


def test_a_z_of_the_wrong_shape_is_refused_even_with_the_right_size():
    policy = make_policy()
    policy.select_action({"observation.state": torch.zeros(1, 2)})
    dim = policy.config.failure_feature_dim
    with pytest.raises(ValueError, match=rf"got shape \(4, {dim // 4}\).*\(1, {dim}\)"):
        policy.report_failure(z=torch.zeros(4, dim // 4))
    assert policy.failure_count().tolist() == [0]


def test_a_training_batch_with_other_windows_than_the_policys_is_refused_naming_them():
    """A dataset loaded with another policy's delta timestamps (here history_length 2) is named, not a shape
    error deep in the UNet."""
    policy = make_policy().train()
    batch = {"observation.state": torch.zeros(4, 3, 2), "action": torch.zeros(4, 18, 2)}
    with pytest.raises(ValueError, match=r"observation windows \(B, 1, D\).*\(B, 16, A\).*delta timestamps"):
        policy.forward(batch)
