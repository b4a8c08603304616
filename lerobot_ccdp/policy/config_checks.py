"""The checks of a `CCDPConfig`: its settings when it is made, the dataset's features when LeRobot validates
them.

They live outside the config's class so that the class reads as its fields and their help. They first moved
for speed (draccus re-read the class's source once per field on every config load); that cost is now taken
away for every config class by `lerobot_ccdp/compat/config_help.py`.
"""

from __future__ import annotations

import copy
import json
import math
import numbers
import os
from dataclasses import fields
from types import UnionType
from typing import TYPE_CHECKING, Literal, get_args, get_origin

from lerobot.configs.parser import get_cli_overrides
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE
from lerobot.utils.utils import is_torch_device_available

if TYPE_CHECKING:
    from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

# Counts and sizes that must be >= 1, and those that must be >= 0.
POSITIVE_FIELDS = (
    "n_obs_steps",
    "horizon",
    "n_action_steps",
    "num_train_timesteps",
    "num_inference_steps",
    "w_z_steps",
    "kernel_size",
    "diffusion_step_embed_dim",
    "spatial_softmax_num_keypoints",
    "dp_star_candidates",
    "dp_star_rounds",
)
NON_NEGATIVE_FIELDS = (
    "delta_z",
    "history_length",
    "scheduler_warmup_steps",
    "failure_guard_steps",
    "z_fourier_octaves",
    "num_primitives",
)
NOISE_SCHEDULERS = ("DDPM", "DDIM")
# The weights of eq. (4) and of the guard's gradient. Each multiplies a difference of unit-variance noise
# estimates, and a reverse step moves its predicted clean chunk by sqrt((1 - alpha_bar_t) / alpha_bar_t)
# times the composed estimate; on the default schedule (squaredcos, 100 steps) that factor is 0.025 at the
# least noisy step and 0.19 to 7 at the others. At a weight of 100 a difference of 0.8 between two estimates
# moves even the last step's chunk across the whole clipping range [-1, 1], so the actions are decided by the
# clipping and sit on their bounds (`w_z=1e30` pinned every action). The shipped configs and benchmarks use at
# most 10 (`w_z`) and 16 (`failure_guard_weight`).
WEIGHT_FIELDS = ("w_h", "w_z", "failure_guard_weight")
MAX_WEIGHT = 100.0
# Fourier octaves of z: sin and cos of 2^k pi z in float32, whose 24-bit mantissa leaves z (about 1 in
# normalised units) a step of 2^-23; at k = 16 that step moves the angle by pi / 128, at k = 23 by pi (the
# features are rounding noise), and from k = 127 the scale is inf and the features NaN. The shipped
# label-free configs use 4.
MAX_FOURIER_OCTAVES = 16
# Bytes per float32 weight or activation, and per step of the noise schedule: diffusers keeps betas, alphas
# and alphas_cumprod (float32) and the timesteps (int64).
FLOAT_BYTES = 4
SCHEDULE_BYTES_PER_STEP = 3 * FLOAT_BYTES + 8


def check_settings(config: CCDPConfig) -> None:
    """Refuse settings the policy cannot run, naming the flag to change (`CCDPConfig.__post_init__`); derive
    `crop_shape` from `crop_ratio` as LeRobot's DiffusionConfig does."""
    _check_number_flags(config)
    _check_numbers(config)
    if config.prediction_type != "epsilon":
        raise ValueError(
            f"CCDP composes noise estimates (eq. 4), so `prediction_type` must be 'epsilon'; got "
            f"{config.prediction_type!r}. Remove --policy.prediction_type or set it to epsilon."
        )
    for name in WEIGHT_FIELDS:
        if getattr(config, name) < 0:
            raise ValueError(
                f"`{name}` must be >= 0 (eq. 4 uses positive weights); got {getattr(config, name)}."
            )
        if getattr(config, name) > MAX_WEIGHT:
            raise ValueError(
                f"`{name}` must be <= {MAX_WEIGHT:g}; got {getattr(config, name):g}. A weight multiplies a "
                "difference of noise estimates, and one this large pushes every predicted chunk past the "
                "scheduler's clipping range, so every action sits on its bound (the shipped configs and "
                f"benchmarks use at most 16). Set --policy.{name} to {MAX_WEIGHT:g} or less."
            )
    if (config.z_fourier_octaves or 0) > MAX_FOURIER_OCTAVES:
        raise ValueError(
            f"`z_fourier_octaves` must be <= {MAX_FOURIER_OCTAVES}; got {config.z_fourier_octaves}. Beyond, "
            "sin(2^k pi z) of a float32 z is rounding noise, and from 128 octaves features are NaN (the "
            f"shipped configs use 4). Set --policy.z_fourier_octaves to {MAX_FOURIER_OCTAVES} or less."
        )
    if config.w_h > 0 and config.history_length == 0:
        raise ValueError(
            "`w_h` > 0 weighs the history term of eq. (4), which needs a history condition: set "
            "--policy.history_length to 1 or more, or --policy.w_h=0."
        )
    _check_choices(config)
    _check_head(config)
    _check_device(config)
    _check_vision(config)
    if config.failure_feature == "primitive" and config.num_primitives < 2:
        raise ValueError(
            "failure_feature='primitive' needs `num_primitives` >= 2 (the number of distinct labels in "
            f"the dataset column {config.primitive_key!r}); got {config.num_primitives}."
        )
    guard_weight_set = config.failure_guard_weight not in (1.0, type(config).failure_guard_weight)
    if guard_weight_set and not config.failure_guard_steps:
        # The default weight and the neutral 1 (what a config saved before the guard's defaults holds) set
        # nothing without guarded steps; any other weight is a setting that would do nothing.
        raise ValueError(
            f"`failure_guard_weight` ({config.failure_guard_weight}) weighs the guard's gradient at its "
            "guarded steps, and `failure_guard_steps` is 0: set --policy.failure_guard_steps or remove "
            "--policy.failure_guard_weight."
        )
    if not 0.0 <= config.state_failure_sets <= 1.0:
        raise ValueError(
            f"`state_failure_sets` is a share of rows in [0, 1]; got {config.state_failure_sets}."
        )
    if config.horizon % 2 ** len(config.down_dims) != 0:
        raise ValueError(
            f"`horizon` ({config.horizon}) must be a multiple of 2**len(down_dims) = "
            f"{2 ** len(config.down_dims)}."
        )
    if config.n_action_steps > config.horizon - config.n_obs_steps + 1:
        raise ValueError(
            f"`n_action_steps` ({config.n_action_steps}) must be <= horizon - n_obs_steps + 1 "
            f"({config.horizon - config.n_obs_steps + 1})."
        )
    _check_memory(config)


def _check_numbers(config: CCDPConfig) -> None:
    """Every number finite, and the sizes of a chunk positive: NaN passes every `<` check (a NaN weight
    gave NaN actions that lerobot-eval scored as failed episodes, a NaN delta_z a DP* that never rejects),
    and n_action_steps 0 trains, then fails at the first action."""
    for f in fields(config):
        value = getattr(config, f.name)
        values = value if isinstance(value, (list, tuple)) else [value]
        kind = _number_kind(f.type)
        if kind is not None and not all(v is None or _is(kind, v) for v in values):
            what = {int: "a whole number", float: "a number", bool: "true or false"}[kind]
            listed = any(get_origin(t) in (list, tuple) for t in (f.type, *get_args(f.type)))
            each = " in each entry" if listed else ""
            raise ValueError(
                f"`{f.name}` takes {what}{each}; got {value!r} "
                f"({type(value).__name__}). A config edited in Python, or a config.json, is used as it is "
                f"(no flag parsing converts it): write {f.name} as {what}."
            )
        if any(isinstance(v, float) and not math.isfinite(v) for v in values):
            raise ValueError(
                f"`{f.name}` must be a finite number; got {value}. Set --policy.{f.name} to a "
                "number (its default is in `lerobot-train --policy.type=ccdp --help`)."
            )
    at_least = dict.fromkeys(POSITIVE_FIELDS, 1) | dict.fromkeys(NON_NEGATIVE_FIELDS, 0)
    small = [
        f"`{name}` must be >= {low} (got {getattr(config, name)})"
        for name, low in at_least.items()
        if getattr(config, name) is not None and getattr(config, name) < low
    ]
    if not config.down_dims or min(config.down_dims) < 1:
        small.append(f"`down_dims` must be a non-empty list of channel counts >= 1 (got {config.down_dims})")
    if small:
        raise ValueError(
            f"{'; '.join(small)}. Set each named --policy.<field> (its default is in "
            "`lerobot-train --policy.type=ccdp --help`)."
        )
    if config.num_inference_steps is not None and config.num_inference_steps > config.num_train_timesteps:
        raise ValueError(
            f"`num_inference_steps` ({config.num_inference_steps}) cannot exceed `num_train_timesteps` "
            f"({config.num_train_timesteps}): the reverse diffusion visits training timesteps."
        )


# What a policy is built from: its networks' sizes, the noise schedule, the failure feature's layout, the
# watched file. A change to one of them after the policy is made cannot take effect.
BUILT_FROM = (
    "input_features",
    "output_features",
    "n_obs_steps",
    "horizon",
    "n_action_steps",
    "history_length",
    "down_dims",
    "kernel_size",
    "n_groups",
    "diffusion_step_embed_dim",
    "use_film_scale_modulation",
    "vision_backbone",
    "vision_backbone_stages",
    "resize_shape",
    "crop_ratio",
    "spatial_softmax_num_keypoints",
    "use_separate_rgb_encoder_per_camera",
    "use_group_norm",
    "noise_scheduler_type",
    "num_train_timesteps",
    "beta_schedule",
    "beta_start",
    "beta_end",
    "prediction_type",
    "clip_sample",
    "clip_sample_range",
    "recovery_head",
    "failure_feature",
    "failure_state_dims",
    "num_primitives",
    "z_fourier_octaves",
    "failure_signal_file",
)


def settings_of(config: CCDPConfig) -> dict:
    """A copy of every field of `config`, to see later whether it was edited (`edited_since`)."""
    return {f.name: copy.deepcopy(getattr(config, f.name)) for f in fields(config)}


def edited_since(config: CCDPConfig, settings: dict) -> bool:
    """Whether `config` was edited since `settings` (`settings_of`) were taken; an edit is checked as
    `CCDPConfig()` checks its settings, and one the policy cannot take is refused. Edits after loading
    (`policy.config.recovery_mode = "dp"`) are how the tests and benchmarks switch modes, and went unchecked:
    recovery_mode "foo" raised KeyError 'foo', n_action_steps 0 an IndexError, and a new w_z was ignored."""
    edited = [name for name, value in settings.items() if getattr(config, name) != value]
    if not edited:
        return False
    fixed = [
        f"{name} ({settings[name]!r} -> {getattr(config, name)!r})" for name in edited if name in BUILT_FROM
    ]
    if fixed:
        raise ValueError(
            f"policy.config was edited after the policy was made: {', '.join(fixed)}. The policy was built "
            "with the old value (network sizes, noise schedule, failure feature, the watched file), so the "
            "edit cannot take effect. Edit the config before loading: config = "
            "PreTrainedConfig.from_pretrained(path); config.<field> = ...; "
            "CCDPPolicy.from_pretrained(path, config=config)."
        )
    check_settings(config)
    return True


def refuse_mistyped_json(saved: dict, file: str) -> None:
    """Refuse a ccdp config.json whose numbers are written as true/false or strings, or whose switches as
    numbers or strings: draccus converts them as it reads the file ("w_z": true became w_z 1.0, "horizon":
    "16" horizon 16), so the checks made after it cannot see what the file says."""
    from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

    for f in fields(CCDPConfig):
        kind, value = _number_kind(f.type), saved.get(f.name)
        values = value if isinstance(value, list) else [value]
        allowed = (bool,) if kind is bool else (int, float)
        if kind is None or all(v is None or type(v) in allowed for v in values):
            continue
        what = {int: "a whole number", float: "a number", bool: "true or false"}[kind]
        raise ValueError(
            f'{file} says "{f.name}": {json.dumps(value)}; it takes {what}. A hand-edited value: write it '
            "as a JSON number (or true/false for a switch), without quotes."
        )


def _check_number_flags(config: CCDPConfig) -> None:
    """Refuse a --policy.<number>=<text> on the command line that is no number: draccus reads "true" and
    "yes" as 1.0 and "0x10" as 16, so `--policy.w_z=true` ran with w_z 1 and said nothing."""
    kinds = {f.name: _number_kind(f.type) for f in fields(config) if f.type in (int, float, int | None)}
    defaults = {f.name: f.default for f in fields(config)}
    for flag in get_cli_overrides("policy") or []:
        name, _, text = flag.removeprefix("--").partition("=")
        if kinds.get(name) is None or text.strip().lower() in ("none", "null"):
            continue
        try:
            kinds[name](text)
        except ValueError:
            raise ValueError(
                f"--policy.{name}={text} is no {'whole number' if kinds[name] is int else 'number'}. "
                f"Write it in digits (its default: --policy.{name}={defaults[name]})."
            ) from None


def _number_kind(annotation: object) -> type | None:
    """int, float or bool for a field holding such values (alone, optional, or in a list or tuple)."""
    args = [a for a in get_args(annotation) if a not in (type(None), Ellipsis)]
    if annotation in (int, float, bool):
        return annotation
    if get_origin(annotation) in (list, tuple, UnionType) and args and len(set(args)) == 1:
        return _number_kind(args[0])
    return None


def _is(kind: type, value: object) -> bool:
    """Whether `value` is a `kind`: a bool is no number (true for a weight was read as 1), a float no
    whole number (horizon=16.0 failed in torch.zeros), an int is a float."""
    if kind is bool:
        return isinstance(value, bool)
    wanted = numbers.Integral if kind is int else numbers.Real
    return isinstance(value, wanted) and not isinstance(value, bool)


def _check_memory(config: CCDPConfig) -> None:
    """Refuse sizes whose allocations exceed this machine's memory, before anything is allocated: a
    checkpoint whose config.json said `"horizon": 1000000000` allocated 16-23 GB for its first action and the
    kernel killed the process without a message."""
    needed = memory_estimate(config)
    total = sum(needed.values())
    memory = _physical_memory()
    if memory is None or total <= memory:
        return
    parts = ", ".join(
        f"{what}: {size / 2**30:,.1f} GiB" for what, size in needed.items() if size >= 0.05 * 2**30
    )
    raise ValueError(
        f"These settings need at least {total / 2**30:,.1f} GiB of memory ({parts}), more than the "
        f"{memory / 2**30:,.1f} GiB this machine has. Lower the sizes named (a checkpoint's config.json "
        "holds the sizes its weights were trained with: a value far from the shipped configs' was edited)."
    )


def memory_estimate(config: CCDPConfig) -> dict[str, int]:
    """Lower bounds, in bytes, of the largest allocations the config's sizes make up to the first action,
    keyed by what drives them: the noise schedule's tables, the convolutions and FiLM condition layers of
    the UNets (LeRobot's: per level two residual blocks of `kernel_size` x channels^2, two more at the
    bottom, each block's FiLM layer from the condition), and one chunk of one row passing the UNet's first
    level. Features not set yet (a config made before the dataset is read) count as size 1 or 0."""
    dims, kernel = list(config.down_dims), config.kernel_size
    action = config.action_feature.shape[-1] if config.action_feature else 1
    frame = config.image_feature_dim + sum(
        math.prod(feature.shape)
        for feature in (config.robot_state_feature, config.env_state_feature)
        if feature is not None
    )
    step = config.diffusion_step_embed_dim
    base_condition = step + config.n_obs_steps * frame + config.history_length * (frame + action) + 2
    from lerobot_ccdp.policy.heads import head_of  # they import the config

    head = head_of(config)
    recovery_condition = head.unet_condition(step, base_condition, _failure_feature_size(config))

    def unet(condition: int) -> int:
        convolutions = kernel * (sum(d * d for d in dims) + 4 * dims[-1] ** 2)
        return convolutions + condition * (2 * sum(dims) + 2 * dims[-1])

    networks = unet(base_condition) + (unet(recovery_condition) if recovery_condition else 0)
    return {
        f"noise schedule (num_train_timesteps={config.num_train_timesteps})": (
            config.num_train_timesteps * SCHEDULE_BYTES_PER_STEP
        ),
        "networks (down_dims, kernel_size, the condition sizes)": networks * FLOAT_BYTES,
        f"one chunk in the UNet (horizon={config.horizon} x down_dims[0])": (
            config.horizon * (action + 2 * dims[0]) * FLOAT_BYTES
        ),
    }


def _failure_feature_size(config: CCDPConfig) -> int:
    """z's size, or 0 while the features it is read from are not set."""
    try:
        return config.failure_feature_dim
    except (AttributeError, KeyError):
        return 0


def _physical_memory() -> int | None:
    """This machine's RAM in bytes (None where the OS does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):
        return None


def _check_head(config: CCDPConfig) -> None:
    """The recovery head's own checks, and no setting of another head (`heads/registry.py`)."""
    from lerobot_ccdp.policy.heads import head_of, refuse_settings_of_other_heads  # they import the config

    refuse_settings_of_other_heads(config)
    head_of(config).check_config(config)


def _check_choices(config: CCDPConfig) -> None:
    """Every `Literal` field holds one of its values (a config file is read without draccus's decoding),
    and the noise scheduler is one diffusers has."""
    allowed = {f.name: get_args(f.type) for f in fields(config) if get_origin(f.type) is Literal}
    allowed["noise_scheduler_type"] = NOISE_SCHEDULERS
    for name, values in allowed.items():
        if getattr(config, name) not in values:
            raise ValueError(f"Unknown `{name}` {getattr(config, name)!r}; choose one of {list(values)}.")


def _check_device(config: CCDPConfig) -> None:
    """LeRobot's config checks the device only when it is made (and then replaces one this machine lacks);
    set later, as in a config edited for `from_pretrained(path, config=...)`, "bogus" failed in safetensors
    ("device bogus is invalid") and "cuda" on a machine without one in torch."""
    try:
        available = config.device is None or is_torch_device_available(config.device)
    except ValueError as error:
        raise ValueError(f"`device` {config.device!r} is no device LeRobot knows: {error}") from None
    if not available:
        raise ValueError(
            f"`device` {config.device!r} is not available on this machine. Set device to 'cpu' or to one "
            "this machine has (LeRobot picks one when the config is made with device None)."
        )


def _check_vision(config: CCDPConfig) -> None:
    """The checks LeRobot's DiffusionConfig makes of the same fields, and its crop derivation."""
    if not config.vision_backbone.startswith("resnet"):
        raise ValueError(
            f"`vision_backbone` must be a torchvision ResNet (e.g. resnet18); got {config.vision_backbone!r}."
        )
    if config.resize_shape is not None and (len(config.resize_shape) != 2 or min(config.resize_shape) <= 0):
        raise ValueError(f"`resize_shape` must be a pair of positive integers; got {config.resize_shape}.")
    if config.vision_backbone_stages not in (1, 2, 3, 4):
        raise ValueError(
            f"`vision_backbone_stages` must be 1 to 4 (a ResNet has 4); got {config.vision_backbone_stages}."
        )
    if not 0 < config.crop_ratio <= 1.0:
        raise ValueError(f"`crop_ratio` must be in (0, 1]; got {config.crop_ratio}.")
    if config.resize_shape is not None:
        ratio = config.crop_ratio
        config.crop_shape = None if ratio == 1.0 else tuple(int(d * ratio) for d in config.resize_shape)
    if config.crop_shape is not None and min(config.crop_shape) <= 0:
        raise ValueError(f"`crop_shape` must have positive dimensions; got {config.crop_shape}.")
    if config.use_group_norm and config.pretrained_backbone_weights:
        raise ValueError(
            "Pretrained backbone weights were trained with BatchNorm: set --policy.use_group_norm=false "
            "to use them (replacing BatchNorm by GroupNorm would discard what they learnt)."
        )


def check_features(config: CCDPConfig) -> None:
    """The dataset's or env's features against what the policy needs (`CCDPConfig.validate_features`)."""
    if config.robot_state_feature is None:
        raise ValueError(
            f"CCDP needs {OBS_STATE!r} among the input features; the dataset or env has "
            f"{sorted(config.input_features)}. Record the robot state as {OBS_STATE!r}."
        )
    _check_images(config)
    _check_head(config)  # again with the features (cameras)
    if config.action_feature is None:
        raise ValueError(f"CCDP needs an {ACTION!r} output feature; the dataset has none.")
    if config.failure_feature == "final_state":
        bad = [d for d in config.failure_state_dims if not 0 <= d < config.state_dim]
        if bad:
            env = config.env_state_feature.shape[0] if config.env_state_feature else 0
            raise ValueError(
                f"`failure_state_dims` {bad} do not exist in the {config.state_dim}-dim state frame "
                f"({OBS_STATE!r} {config.robot_state_feature.shape[0]} dims, then {OBS_ENV_STATE!r} {env}): "
                f"choose --policy.failure_state_dims among 0..{config.state_dim - 1}."
            )


def _check_images(config: CCDPConfig) -> None:
    """Every camera has the same (C, H, W) shape (one encoder shape, as in LeRobot) and fits the crop."""
    shapes = {key: tuple(ft.shape) for key, ft in config.image_features.items()}
    if len(set(shapes.values())) > 1:
        raise ValueError(
            f"All cameras must have the same shape (one encoder input size); got {shapes}. Record them "
            "at one size, or set --policy.resize_shape=[H,W] to resize every camera to it."
        )
    if shapes and config.crop_shape is not None and config.resize_shape is None:
        _, height, width = next(iter(shapes.values()))
        if config.crop_shape[0] > height or config.crop_shape[1] > width:
            raise ValueError(f"`crop_shape` {config.crop_shape} does not fit in the camera images {shapes}.")
