"""One gate for every number: a config's checks run wherever it becomes a policy (CCDPConfig(), a checkpoint's
config.json, a config edited in Python and passed to `from_pretrained(path, config=...)` or CCDPPolicy, and
lerobot-eval's parsing), and a checkpoint's weights are checked before they act."""

import json
import math
import re
import shutil
import sys
from pathlib import Path

import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from safetensors.torch import load_file, save_file

from lerobot_ccdp.compat.cli_errors import buried_error
from lerobot_ccdp.policy.config_checks import MAX_WEIGHT, memory_estimate
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

from fixtures.policy_factory import make_policy


def edited(checkpoint: Path, tmp_path: Path, **fields) -> Path:
    """A copy of `checkpoint` whose config.json says `fields`."""
    copy = shutil.copytree(checkpoint, tmp_path / "edited")
    config = json.loads((copy / "config.json").read_text())
    (copy / "config.json").write_text(json.dumps({**config, **fields}))
    return copy


# ----- item: a config edited in Python gets the same checks ------------------------------------------------

EDITS = [
    ("w_z", math.nan, "`w_z` must be a finite number"),
    ("w_h", math.nan, "`w_h` must be a finite number"),
    ("w_z", math.inf, "`w_z` must be a finite number"),
    ("w_z", -1e30, "`w_z` must be >= 0"),
    ("w_z", 1e30, f"`w_z` must be <= {MAX_WEIGHT:g}"),
    ("n_action_steps", 0, r"`n_action_steps` must be >= 1 \(got 0\)"),
    ("dp_star_rounds", -1, r"`dp_star_rounds` must be >= 1 \(got -1\)"),
    ("dp_star_candidates", 0, r"`dp_star_candidates` must be >= 1 \(got 0\)"),
    # LeRobot checks the device only when a config is made: set later, "bogus" failed in safetensors
    ("device", "bogus", r"`device` 'bogus' is no device LeRobot knows.*cuda, mps, xpu or cpu"),
]


@pytest.mark.parametrize(("name", "value", "message"), EDITS)
def test_a_config_edited_in_python_is_checked_by_from_pretrained(
    untrained_primitive_checkpoint, name, value, message
):
    """Before, only CCDPConfig() and the CLI checked: NaN weights gave NaN actions, inf or -1e30 pinned every
    action, n_action_steps=0 an IndexError."""
    config = PreTrainedConfig.from_pretrained(untrained_primitive_checkpoint)
    setattr(config, name, value)
    with pytest.raises(ValueError, match=message):
        CCDPPolicy.from_pretrained(untrained_primitive_checkpoint, config=config)


@pytest.mark.parametrize(("name", "value", "message"), EDITS[:3])
def test_a_config_edited_in_python_is_checked_by_the_policy(name, value, message):
    config = make_policy().config
    setattr(config, name, value)
    with pytest.raises(ValueError, match=message):
        CCDPPolicy(config)


# ----- item: weights that would pin every action ------------------------------------------------------------


@pytest.mark.parametrize(
    "settings",
    [
        {"w_z": 1e30},
        {"w_h": 101.0},
        {"recovery_head": "set_denoiser", "failure_guard_steps": 2, "failure_guard_weight": 1e3},
    ],
)
def test_a_weight_that_would_pin_every_action_is_refused_with_the_reason(settings):
    name, value = next((k, v) for k, v in settings.items() if k.startswith(("w_", "failure_guard_w")))
    message = rf"`{name}` must be <= 100; got {re.escape(f'{value:g}')}\..*every action sits on its bound"
    with pytest.raises(ValueError, match=message):
        CCDPConfig(**settings)


def test_fourier_octaves_that_would_make_z_noise_or_nan_are_refused():
    with pytest.raises(ValueError, match=r"`z_fourier_octaves` must be <= 16; got 200\..*NaN"):
        CCDPConfig(z_fourier_octaves=200)
    assert CCDPConfig(z_fourier_octaves=16).z_fourier_octaves == 16


def test_the_largest_weight_allowed_is_accepted():
    assert CCDPConfig(w_z=MAX_WEIGHT, w_h=MAX_WEIGHT, history_length=1).w_z == MAX_WEIGHT


def test_a_weight_in_a_checkpoints_config_json_is_refused(untrained_primitive_checkpoint, tmp_path):
    with pytest.raises(ValueError, match=r"`w_z` must be <= 100; got 1e\+30"):
        CCDPPolicy.from_pretrained(edited(untrained_primitive_checkpoint, tmp_path, w_z=1e30))


def test_lerobot_eval_refuses_the_weight_while_parsing(untrained_primitive_checkpoint, tmp_path, monkeypatch):
    """lerobot-eval's own entry point, in-process: refused while it parses, before any env is built. The
    hook of compat/cli_errors.py prints this buried error as the traceback's last line."""
    from lerobot.scripts import lerobot_eval

    argv = [
        "lerobot-eval",
        f"--policy.path={untrained_primitive_checkpoint}",
        "--policy.w_z=1e30",
        "--policy.device=cpu",
        "--env.type=ccdp",
        "--env.task=DoorOpening-lite-v0",
        f"--output_dir={tmp_path / 'eval'}",
    ]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(Exception) as refused:
        lerobot_eval.main()
    assert str(buried_error(refused.value)).startswith("`w_z` must be <= 100; got 1e+30.")
    assert not (tmp_path / "eval").exists()


@pytest.mark.parametrize("flag", ["--policy.w_z=true", "--policy.horizon=0x10"])
def test_a_number_flag_that_is_no_number_is_refused_while_parsing(
    untrained_primitive_checkpoint, monkeypatch, flag
):
    """Before: draccus read --policy.w_z=true as w_z 1.0 and 0x10 as 16, and the run went on."""
    from lerobot.scripts import lerobot_eval

    argv = ["lerobot-eval", f"--policy.path={untrained_primitive_checkpoint}", flag, "--policy.device=cpu"]
    monkeypatch.setattr(sys, "argv", [*argv, "--env.type=ccdp", "--env.task=DoorOpening-lite-v0"])
    with pytest.raises(Exception) as refused:
        lerobot_eval.main()
    assert re.match(
        rf"{re.escape(flag)} is no (whole )?number\. Write it in digits", str(buried_error(refused.value))
    )


# ----- item: sizes that need more memory than the machine has -----------------------------------------------


@pytest.mark.parametrize(
    ("settings", "part"),
    [
        ({"horizon": 2**40}, r"one chunk in the UNet \(horizon=1099511627776 x down_dims\[0\]\)"),
        ({"num_train_timesteps": 10**13}, r"noise schedule \(num_train_timesteps=10000000000000\)"),
        ({"down_dims": (2**20,), "horizon": 16}, r"networks \(down_dims"),
    ],
)
def test_sizes_beyond_the_machines_memory_are_refused_with_the_estimate(settings, part):
    with pytest.raises(
        ValueError, match=rf"need at least [\d,.]+ GiB of memory \(.*{part}.*this machine has"
    ):
        CCDPConfig(**settings)


def test_a_checkpoint_whose_horizon_needs_more_memory_is_refused_before_loading(
    untrained_primitive_checkpoint, tmp_path, monkeypatch
):
    """Before, `"horizon": 1000000000` in config.json made the first action allocate 16-23 GB and the kernel
    killed the process without a message."""
    folder = edited(untrained_primitive_checkpoint, tmp_path, horizon=10**12)
    made = []
    monkeypatch.setattr(CCDPPolicy, "__init__", lambda *args, **kwargs: made.append(args))
    with pytest.raises(ValueError, match=r"horizon=1000000000000.*more than the [\d,.]+ GiB this machine"):
        CCDPPolicy.from_pretrained(folder)
    assert not made


@pytest.mark.parametrize("head", ["unet", "set_denoiser", "classifier"])
def test_the_estimate_of_the_networks_is_a_lower_bound(head):
    """A config refused needs at least the estimate: the estimate never exceeds what construction takes."""
    policy = make_policy(recovery_head=head, env_dim=3, history_length=2)
    actual = sum(t.numel() * t.element_size() for t in policy.state_dict().values())
    networks = next(size for what, size in memory_estimate(policy.config).items() if what.startswith("net"))
    assert actual / 4 < networks <= actual


# ----- item: messages that name the field and the fix -------------------------------------------------------


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"num_primitives": -2}, r"^`num_primitives` must be >= 0 \(got -2\)"),
        ({"down_dims": []}, r"^`down_dims` must be a non-empty list of channel counts >= 1 \(got \(\)\)"),
    ],
)
def test_a_bad_size_in_config_json_is_named_through_the_api(
    untrained_primitive_checkpoint, tmp_path, fields, message
):
    """Before, PreTrainedConfig.from_pretrained raised only draccus's "Couldn't instantiate class
    CCDPConfig"."""
    folder = edited(untrained_primitive_checkpoint, tmp_path, **fields)
    with pytest.raises(ValueError, match=message):
        PreTrainedConfig.from_pretrained(folder)
    with pytest.raises(ValueError, match=message):
        CCDPPolicy.from_pretrained(folder)


def test_a_size_message_names_each_fields_own_bound():
    with pytest.raises(ValueError) as refused:
        CCDPConfig(history_length=-1, horizon=0)
    assert str(refused.value).startswith(
        "`horizon` must be >= 1 (got 0); `history_length` must be >= 0 (got -1)."
    )


def test_a_ccdp_config_saying_type_diffusion_is_named_with_the_fix(untrained_primitive_checkpoint, tmp_path):
    folder = edited(untrained_primitive_checkpoint, tmp_path, type="diffusion")
    message = (
        rf'{folder / "config.json"} says "type": "diffusion", but its fields are those of a \'ccdp\' policy '
        r"config \(a 'diffusion' config has no delta_z, dp_star_candidates, dp_star_rounds, \.\.\.\)\. "
        r'If the file was edited, set "type": "ccdp" again'
    )
    with pytest.raises(ValueError, match=message):
        PreTrainedConfig.from_pretrained(folder)
    with pytest.raises(ValueError, match=message):
        CCDPPolicy.from_pretrained(folder)


def test_a_diffusion_config_saying_type_ccdp_is_named_with_the_fix(tmp_path):
    DiffusionConfig(device="cpu")._save_pretrained(tmp_path)
    config = json.loads((tmp_path / "config.json").read_text())
    (tmp_path / "config.json").write_text(json.dumps({**config, "type": "ccdp"}))
    with pytest.raises(
        ValueError,
        match=r"but its fields are those of a 'diffusion' policy config \(a 'ccdp' config has no "
        r"compile_mode, compile_model, drop_n_last_frames\)",
    ):
        PreTrainedConfig.from_pretrained(tmp_path)


def test_a_state_shape_edited_in_config_json_is_named_with_both_sizes(
    untrained_primitive_checkpoint, tmp_path
):
    config = json.loads((untrained_primitive_checkpoint / "config.json").read_text())
    config["input_features"]["observation.state"]["shape"] = [3]
    folder = edited(untrained_primitive_checkpoint, tmp_path, input_features=config["input_features"])
    with pytest.raises(
        ValueError,
        match=r"is to read observation.state \(3,\), 3 values per frame, but the weights in .* were trained "
        r"on 2 \(model.constant_inputs.value\)\. If its config.json's input_features were edited, restore",
    ):
        CCDPPolicy.from_pretrained(folder)


# ----- item: loaded weights are finite ----------------------------------------------------------------------


@pytest.mark.parametrize("tensor", ["model.base.unet.final_conv.1.bias", "model.outcomes.chunks"])
def test_non_finite_weights_are_refused_at_load_naming_the_tensor(
    untrained_primitive_checkpoint, tmp_path, tensor
):
    """Before, they loaded and select_action returned non-finite actions (or DP* looked chunks up in a table
    holding NaN)."""
    folder = shutil.copytree(untrained_primitive_checkpoint, tmp_path / "nan_weights")
    weights = load_file(folder / "model.safetensors")
    weights[tensor].view(-1)[0] = torch.nan
    save_file(weights, folder / "model.safetensors")
    with pytest.raises(
        ValueError, match=rf"hold NaN or inf in 1 tensor\(s\) \({tensor}\).*earlier checkpoint"
    ):
        CCDPPolicy.from_pretrained(folder)


# ----- item: values of another type, configs of another kind, edits after loading --------------------------


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("horizon", 16.0, r"`horizon` takes a whole number; got 16.0 \(float\)"),
        ("n_action_steps", 2.5, r"`n_action_steps` takes a whole number; got 2.5"),
        ("w_z", True, r"`w_z` takes a number; got True \(bool\)"),
        ("down_dims", (32, 64.0), r"`down_dims` takes a whole number in each entry"),
    ],
)
def test_a_value_of_another_type_in_an_edited_config_is_named(
    untrained_primitive_checkpoint, name, value, message
):
    """Before: horizon=16.0 or n_action_steps=2.5 passed every check and failed in torch.zeros at the first
    action; w_z=True was taken as 1."""
    config = PreTrainedConfig.from_pretrained(untrained_primitive_checkpoint)
    setattr(config, name, value)
    with pytest.raises(ValueError, match=message):
        CCDPPolicy.from_pretrained(untrained_primitive_checkpoint, config=config)


@pytest.mark.parametrize(
    "config", [DiffusionConfig(), {"w_z": 2.0}, CCDPConfig()], ids=["diffusion", "dict", "bare"]
)
def test_a_config_that_is_not_the_checkpoints_own_is_named_with_the_fix(
    untrained_primitive_checkpoint, config
):
    """Before: a DiffusionConfig or a dict was told the ccdp checkpoint "is a 'ccdp' checkpoint, not a ccdp
    one", and a CCDPConfig() without features that the dataset lacked observation.state."""
    with pytest.raises(
        ValueError, match=r"is a ccdp checkpoint, and the config given.*PreTrainedConfig.from_pretrained"
    ):
        CCDPPolicy.from_pretrained(untrained_primitive_checkpoint, config=config)


def _first_action(policy: CCDPPolicy) -> torch.Tensor:
    with torch.inference_mode():
        return policy.select_action({"observation.state": torch.zeros(1, 2)})


def test_an_edit_of_policy_config_after_loading_is_checked_and_applied():
    """Modes are switched by editing policy.config after loading (tests, benchmarks). Before, such an edit
    was never checked (recovery_mode 'foo' raised KeyError 'foo', n_action_steps 0 an IndexError), and a new
    weight was ignored: the weights of eq. (4) were read once, when the policy was made."""
    policy = make_policy()
    policy.config.w_z = 3.0
    _first_action(policy)
    assert policy.model.weights.w_z == 3.0
    policy.config.recovery_mode = "foo"
    with pytest.raises(ValueError, match=r"Unknown `recovery_mode` 'foo'"):
        _first_action(policy)
    policy.config.recovery_mode = "dp"
    policy.config.horizon = 32
    with pytest.raises(
        ValueError, match=r"edited after the policy was made: horizon \(16 -> 32\).*config=config"
    ):
        _first_action(policy)
