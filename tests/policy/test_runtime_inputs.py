"""What enters the policy at run time, through the routes a user takes: a checkpoint loaded as the README's
robot snippet loads it (its own pre/post processors, `select_action` under torch.inference_mode() as
lerobot-eval calls it), report_failure() from a control loop, the failure signal file, and the demonstrations
that become a checkpoint's outcome table. Every input is refused where it enters, naming it, the value and the
fix; no NaN action is ever returned (issue 110). Each test failed before that issue's change: the 1e20 state
gave saturated or NaN actions, a NaN flag read as "no failure", a NaN demo frame reached the outcome table."""

import re
import shutil
from dataclasses import replace

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.policies.factory import make_policy as lerobot_make_policy
from lerobot.policies.factory import make_pre_post_processors
from lerobot.utils.constants import OBS_IMAGES, OBS_STATE
from safetensors.torch import load_file, save_file

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

from fixtures.policy_factory import make_policy
from fixtures.reaching import REACHING_REPO_ID

FLAG = "observation.failure"


def _readme_policy(checkpoint):
    """The README's robot snippet: the policy and the processors saved with it."""
    policy = CCDPPolicy.from_pretrained(checkpoint)
    pre, post = make_pre_post_processors(policy.config, checkpoint)
    return policy, pre, post


def _act(policy, pre, post, observation: dict) -> torch.Tensor:
    with torch.inference_mode():
        return post(policy.select_action(pre(observation)))


# ----- observations -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("value", [1e20, -3e4])
def test_a_reading_far_outside_the_data_is_refused_naming_it_and_the_units(
    untrained_primitive_checkpoint, value
):
    policy, pre, post = _readme_policy(untrained_primitive_checkpoint)
    assert torch.isfinite(_act(policy, pre, post, {OBS_STATE: torch.tensor([[0.3, -0.2]])})).all()
    policy.reset()
    at = re.escape(f"observation.state[1] is {value:.4g} after normalisation")
    with pytest.raises(ValueError, match=rf"{at}.*units"):
        _act(policy, pre, post, {OBS_STATE: torch.tensor([[0.3, value]])})
    assert policy._rollout is None, "nothing was remembered of the refused observation"


def test_a_camera_image_that_is_not_finite_or_far_outside_is_refused_naming_the_camera():
    camera = f"{OBS_IMAGES}.front"
    config = CCDPConfig(
        input_features={
            OBS_STATE: PolicyFeature(FeatureType.STATE, (2,)),
            camera: PolicyFeature(FeatureType.VISUAL, (3, 48, 48)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
        failure_feature="action",
        vision_backbone_stages=3,
        crop_shape=None,
        device="cpu",
    )
    policy = CCDPPolicy(config).eval()
    image = torch.zeros(1, 3, 48, 48)
    for bad, message in [(float("nan"), "contains NaN or inf"), (4e3, "is 4000 after normalisation")]:
        image[0, 1, 5, 7] = bad
        with torch.inference_mode(), pytest.raises(ValueError, match=rf"'{camera}'.*{message}"):
            policy.select_action({OBS_STATE: torch.zeros(1, 2), camera: image})


def test_non_finite_actions_are_never_returned_and_their_cause_is_named(untrained_primitive_checkpoint):
    policy, pre, post = _readme_policy(untrained_primitive_checkpoint)
    observation = {OBS_STATE: torch.tensor([[0.3, -0.2]])}
    weight = policy.model.base.state_dict()
    name = next(k for k, v in weight.items() if v.is_floating_point() and v.ndim > 1)
    with torch.no_grad():
        weight[name].fill_(float("nan"))  # a tensor edited in Python after loading
    with pytest.raises(
        FloatingPointError, match=rf"NaN or inf actions for row\(s\) \[0\].*{re.escape(f'model.base.{name}')}"
    ):
        _act(policy, pre, post, observation)

    policy, pre, post = _readme_policy(untrained_primitive_checkpoint)
    policy.model.weights = replace(policy.model.weights, w_s=float("nan"))  # weights edited in Python
    with pytest.raises(FloatingPointError, match=r"tensors and inputs are finite.*settings w_s=nan"):
        _act(policy, pre, post, observation)


def test_initial_noise_that_is_not_finite_or_of_another_shape_is_refused():
    policy = make_policy()
    state = {OBS_STATE: torch.zeros(2, 2)}
    with pytest.raises(ValueError, match=r"noise= got shape \(2, 3\).*\(2, 16, 2\)"):
        policy.select_action(state, noise=torch.zeros(2, 3))
    with pytest.raises(ValueError, match="noise= holds NaN or inf"):
        policy.predict_action_chunk(state, noise=torch.full((2, 16, 2), float("nan")))


def test_a_camera_image_of_integers_is_named_and_one_of_float64_is_read_as_float32():
    """Before: a uint8 camera frame or a float64 image failed in the encoder's convolution ("expected
    scalar type Byte but found Float")."""
    camera = f"{OBS_IMAGES}.front"
    config = CCDPConfig(
        input_features={
            OBS_STATE: PolicyFeature(FeatureType.STATE, (2,)),
            camera: PolicyFeature(FeatureType.VISUAL, (3, 32, 32)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
        failure_feature="action",
        vision_backbone_stages=1,
        crop_shape=None,
        down_dims=(32, 64),
        device="cpu",
    )
    policy = CCDPPolicy(config).eval()
    image = torch.full((1, 3, 32, 32), 200, dtype=torch.uint8)
    with pytest.raises(ValueError, match=rf"'{camera}' holds torch.uint8 values.*image.float\(\) / 255"):
        policy.select_action({OBS_STATE: torch.zeros(1, 2), camera: image})
    action = policy.select_action({OBS_STATE: torch.zeros(1, 2), camera: image.double() / 255})
    assert action.dtype == torch.float32 and torch.isfinite(action).all()


@pytest.mark.parametrize(
    ("move", "message"),
    [
        (lambda p: p.to("meta"), r"weights are on the meta device.*from_pretrained"),
        (lambda p: p.half(), r"weights are torch.float16.*policy.float\(\)"),
    ],
)
def test_a_policy_moved_to_meta_or_half_precision_is_named_before_acting(move, message):
    """Before: "Tensor.item() cannot be called on meta tensors" and "mat1 and mat2 must have the same
    dtype" from inside the networks."""
    policy = move(make_policy())
    with pytest.raises(RuntimeError, match=message):
        policy.select_action({OBS_STATE: torch.zeros(1, 2)})


@pytest.mark.parametrize(
    ("noise", "message"),
    [
        (
            torch.zeros(2, 16, 2, dtype=torch.float64),
            r"noise= got shape \(2, 16, 2\) of torch.float64.*float32",
        ),
        (torch.zeros(2, 16, 2, dtype=torch.long), r"of torch.int64.*float32"),
        (torch.full((2, 16, 2), 1e30), r"noise= holds 1e\+30.*standard normal"),
    ],
)
def test_initial_noise_of_another_dtype_or_far_from_normal_is_refused(noise, message):
    """Before: float64 or integer noise failed deep in the UNet ("Input type (double) and bias type (float)"),
    and noise of 1e30 made NaN actions blamed on the weights w_s, w_h, w_z."""
    with pytest.raises(ValueError, match=message):
        make_policy().select_action({OBS_STATE: torch.zeros(2, 2)}, noise=noise)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float16])
def test_a_state_of_another_dtype_is_read_as_float32(dtype):
    """Before: a float64 or float16 state (numpy's default, a half-precision sensor driver) failed in the
    UNet ("mat1 and mat2 must have the same dtype") or in the rollout memory."""
    policy = make_policy()
    torch.manual_seed(0)
    expected = policy.select_action({OBS_STATE: torch.tensor([[1.0, -2.0]])})
    policy.reset()
    torch.manual_seed(0)
    assert torch.equal(policy.select_action({OBS_STATE: torch.tensor([[1.0, -2.0]], dtype=dtype)}), expected)


# ----- the failure flag ----------------------------------------------------------------------------------


@pytest.mark.parametrize("flag", [float("nan"), 0.5, -1.0, float("inf")])
def test_a_failure_flag_other_than_0_or_1_is_refused_naming_the_key(untrained_primitive_checkpoint, flag):
    policy, pre, post = _readme_policy(untrained_primitive_checkpoint)
    state = {OBS_STATE: torch.zeros(2, 2)}
    _act(policy, pre, post, state)
    with pytest.raises(ValueError, match=rf"'{FLAG}' holds \[{flag}\] in row\(s\) \[1\].*1 \(the attempt"):
        _act(policy, pre, post, {**state, FLAG: torch.tensor([[0.0], [flag]])})
    assert policy.failure_count().tolist() == [0, 0]


def test_a_failure_flag_of_another_shape_names_the_shape_it_takes(untrained_primitive_checkpoint):
    """(B, 2) used to be read by its first column and (3,) for 2 rows to end in a raw torch reshape error."""
    policy, pre, post = _readme_policy(untrained_primitive_checkpoint)
    state = {OBS_STATE: torch.zeros(2, 2)}
    _act(policy, pre, post, state)
    for shape in [(3,), (2, 2), (1, 2, 1), (4, 1)]:
        named = re.escape(f"'{FLAG}' has shape {shape}")
        with pytest.raises(ValueError, match=rf"{named}.*\(2, 1\) or \(2,\).*reshape\(2, 1\)"):
            _act(policy, pre, post, {**state, FLAG: torch.ones(shape)})
    assert policy.failure_count().tolist() == [0, 0]
    for flag in [torch.tensor([[0.0], [1.0]]), torch.tensor([False, True]), torch.tensor([0, 1])]:
        _act(policy, pre, post, {**state, FLAG: flag})  # what env wrappers and control loops send
    assert policy.failure_count().tolist() == [0, 3]


def test_a_failure_flag_that_is_not_numbers_is_named():
    """Before: torch's "new(): invalid data type 'str'"."""
    policy = make_policy()
    with pytest.raises(ValueError, match=rf"'{FLAG}' is 'yes'; it takes numbers, one flag per row"):
        policy.select_action({OBS_STATE: torch.zeros(1, 2), FLAG: "yes"})


# ----- report_failure --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("z", "message"),
    [
        ("abc", r"report_failure\(z='abc'\) got a str; it takes one normalised z per failed row, \(1, 32\)"),
        (torch.full((1, 32), 1e30), r"report_failure\(z=...\) holds 1e\+30, beyond the \+-1000.*normalised"),
    ],
)
def test_report_failure_names_a_z_that_is_not_numbers_or_far_outside(z, message):
    """Before: a str gave torch's "new(): invalid data type 'str'", and z = 1e30 was recorded as a failure."""
    policy = make_policy()
    policy.select_action({OBS_STATE: torch.zeros(1, 2)})
    with pytest.raises(ValueError, match=message):
        policy.report_failure(z=z)
    assert policy.failure_count().tolist() == [0]


def test_report_failure_names_the_forms_rows_takes(untrained_primitive_checkpoint):
    policy, pre, post = _readme_policy(untrained_primitive_checkpoint)
    _act(policy, pre, post, {OBS_STATE: torch.zeros(3, 2)})
    for rows in ["0", b"0", 0.0, True, [0.5], [[0]], {0}, object()]:
        with pytest.raises(TypeError, match=r"report_failure\(rows=.*rows takes None \(every row\), a row"):
            policy.report_failure(rows=rows)
    assert policy.failure_count().tolist() == [0, 0, 0]
    for rows in [0, np.int64(2), [1], (0, 2), torch.tensor([False, True, False]), np.array([2]), []]:
        policy.report_failure(rows=rows)
    assert policy.failure_count().tolist() == [2, 2, 3]
    with pytest.raises(ValueError, match=r"acts on 3 row\(s\), indices 0\.\.2 \(or a bool mask"):
        policy.report_failure(rows=[True, False])


def test_report_failure_before_any_action_since_reset_says_select_action_comes_first(
    untrained_primitive_checkpoint,
):
    policy, pre, post = _readme_policy(untrained_primitive_checkpoint)
    _act(policy, pre, post, {OBS_STATE: torch.zeros(1, 2)})
    policy.reset()
    with pytest.raises(RuntimeError, match=r"before any select_action\(\) since.*reset\(\).*no attempt"):
        policy.report_failure()
    # and a wrong rows is named as such even then
    with pytest.raises(TypeError, match=r"rows takes None"):
        policy.report_failure(rows="all")


# ----- the failure signal file ------------------------------------------------------------------------------


@pytest.mark.parametrize("path", ["/tmp/ccdp\x00failed", "\x00"])
def test_a_nul_byte_in_the_signal_path_is_refused_naming_the_setting(
    untrained_primitive_checkpoint, reaching_root, path
):
    """As lerobot-record loads the policy: the checkpoint's config with the command line's overrides."""
    config = PreTrainedConfig.from_pretrained(
        untrained_primitive_checkpoint, cli_overrides=[f"--failure_signal_file={path}"]
    )
    config.pretrained_path = untrained_primitive_checkpoint
    with pytest.raises(
        ValueError, match=r"--policy\.failure_signal_file=.*holds a NUL byte.*/tmp/ccdp_failed"
    ):
        lerobot_make_policy(config, ds_meta=LeRobotDatasetMetadata(REACHING_REPO_ID, root=reaching_root))


# ----- the outcome table ------------------------------------------------------------------------------------


def _damage_one_frame(root, column: str, row: int) -> tuple[int, int]:
    """Set `column` to NaN at one row of the dataset's first data file, leaving stats.json as it was (computed
    before the damage); returns the (episode, frame) of that row."""
    file = sorted((root / "data").rglob("*.parquet"))[0]
    table = pq.read_table(file)
    values = np.stack(table.column(column).to_numpy(zero_copy_only=False)).astype(np.float32)
    values[row, -1] = np.nan
    array = pa.FixedSizeListArray.from_arrays(pa.array(values.ravel()), values.shape[1])
    pq.write_table(table.set_column(table.schema.get_field_index(column), column, array), file)
    return table.column("episode_index")[row].as_py(), table.column("frame_index")[row].as_py()


@pytest.mark.parametrize("column", ["action", OBS_STATE])
def test_a_nan_demo_frame_is_refused_before_it_reaches_the_outcome_table(reaching_root, tmp_path, column):
    """As lerobot-train builds a fresh policy (LeRobot's make_policy with the dataset's metadata): the table
    reads every frame, including those no training batch draws."""
    root = tmp_path / "damaged"
    shutil.copytree(reaching_root, root)
    episode, frame = _damage_one_frame(root, column, 37)
    config = CCDPConfig(failure_feature="primitive", num_primitives=4, device="cpu")
    with pytest.raises(
        ValueError,
        match=rf"'{REACHING_REPO_ID}' at .*damaged holds NaN or inf in column '{column}' at episode "
        rf"{episode}, frame {frame} \(1 frame\(s\) in all\).*recompute the dataset's stats",
    ):
        lerobot_make_policy(config, ds_meta=LeRobotDatasetMetadata(REACHING_REPO_ID, root=root))


def test_a_checkpoint_whose_outcome_table_holds_nan_is_refused_at_load(
    untrained_primitive_checkpoint, tmp_path
):
    """The table is a buffer of the state dict (model.outcomes.*), so the finiteness check of every loaded
    tensor covers it: DP* used to run on it without a word."""
    crafted = tmp_path / "crafted"
    shutil.copytree(untrained_primitive_checkpoint, crafted)
    weights = load_file(crafted / "model.safetensors")
    weights["model.outcomes.chunks"][5, 3] = float("nan")
    save_file(weights, crafted / "model.safetensors", metadata={"format": "pt"})
    with pytest.raises(ValueError, match=r"model\.outcomes\.chunks"):
        CCDPPolicy.from_pretrained(crafted)
