"""The checks of a `CCDPConfig`: its settings when it is made, the dataset's features when LeRobot validates
them.

They live outside the config's class so that the class reads as its fields and their help. They first moved
for speed (draccus re-read the class's source once per field on every config load); that cost is now taken
away for every config class by `lerobot_ccdp/compat/config_help.py`.
"""

from __future__ import annotations

import math
from dataclasses import fields
from typing import TYPE_CHECKING, Literal, get_args, get_origin

from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE

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
    "ccdp_redraws",
    "scheduler_warmup_steps",
    "w_z_from_step",
    "failure_guard_steps",
    "z_fourier_octaves",
)
NOISE_SCHEDULERS = ("DDPM", "DDIM")


def check_settings(config: CCDPConfig) -> None:
    """Refuse settings the policy cannot run, naming the flag to change (`CCDPConfig.__post_init__`); derive
    `crop_shape` from `crop_ratio` as LeRobot's DiffusionConfig does."""
    _check_numbers(config)
    if config.prediction_type != "epsilon":
        raise ValueError(
            f"CCDP composes noise estimates (eq. 4), so `prediction_type` must be 'epsilon'; got "
            f"{config.prediction_type!r}. Remove --policy.prediction_type or set it to epsilon."
        )
    for name in ("w_s", "w_h", "w_z", "failure_guard_weight"):
        if getattr(config, name) < 0:
            raise ValueError(
                f"`{name}` must be >= 0 (eq. 4 uses positive weights); got {getattr(config, name)}."
            )
    if config.w_h > 0 and config.history_length == 0:
        raise ValueError(
            "`w_h` > 0 weighs the history term of eq. (4), which needs a history condition: set "
            "--policy.history_length to 1 or more, or --policy.w_h=0."
        )
    _check_choices(config)
    _check_vision(config)
    if config.failure_state_key not in (OBS_STATE, OBS_ENV_STATE):
        raise ValueError(
            f"`failure_state_key` must be {OBS_STATE!r} or {OBS_ENV_STATE!r}; got "
            f"{config.failure_state_key!r}."
        )
    if config.failure_feature == "primitive" and config.num_primitives < 2:
        raise ValueError(
            "failure_feature='primitive' needs `num_primitives` >= 2 (the number of distinct labels in "
            f"the dataset column {config.primitive_key!r}); got {config.num_primitives}."
        )
    bad_steps = [s for s in config.failure_action_steps if not 0 <= s < config.horizon]
    if bad_steps:
        raise ValueError(f"`failure_action_steps` {bad_steps} fall outside the chunk [0, {config.horizon}).")
    if (config.w_z_steps is not None or config.w_z_from_step) and config.recovery_head != "set_denoiser":
        raise ValueError(
            f"`w_z_steps` ({config.w_z_steps}) and `w_z_from_step` ({config.w_z_from_step}) schedule the set "
            f"denoiser's failure weight; the {config.recovery_head!r} head weighs every step alike. Remove "
            "--policy.w_z_steps and --policy.w_z_from_step or use --policy.recovery_head=set_denoiser."
        )
    if config.failure_guard_steps and config.recovery_head != "set_denoiser":
        raise ValueError(
            f"`failure_guard_steps` ({config.failure_guard_steps}) guides the set denoiser's last reverse "
            f"steps with its guard; the {config.recovery_head!r} head has none. Remove "
            "--policy.failure_guard_steps or use --policy.recovery_head=set_denoiser."
        )
    if config.failure_guard_weight != 1 and not config.failure_guard_steps:
        raise ValueError(
            f"`failure_guard_weight` ({config.failure_guard_weight}) weighs the guard's gradient at its "
            "guarded steps, and `failure_guard_steps` is 0: set --policy.failure_guard_steps or remove "
            "--policy.failure_guard_weight."
        )
    if config.stratum_weights and config.recovery_head != "set_denoiser":
        raise ValueError(
            f"`stratum_weights` weighs the set denoiser's training rows; the {config.recovery_head!r} head "
            "has no failure-set strata. Remove --policy.stratum_weights or use "
            "--policy.recovery_head=set_denoiser."
        )
    if not 0.0 <= config.state_failure_sets <= 1.0:
        raise ValueError(
            f"`state_failure_sets` is a share of rows in [0, 1]; got {config.state_failure_sets}."
        )
    if config.state_failure_sets and config.recovery_head != "set_denoiser":
        raise ValueError(
            f"`state_failure_sets` draws the set denoiser's training failure sets; the "
            f"{config.recovery_head!r} head has none. Remove --policy.state_failure_sets or use "
            "--policy.recovery_head=set_denoiser."
        )
    if config.recovery_head == "set_denoiser" and config.n_obs_steps != 1:
        raise ValueError(
            f"recovery_head='set_denoiser' trains on one-frame rows of a synthesised dataset: it needs "
            f"n_obs_steps=1; got {config.n_obs_steps}. Use --policy.recovery_head=unet."
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


def _check_numbers(config: CCDPConfig) -> None:
    """Every number finite, and the sizes of a chunk positive: NaN passes every `<` check (a NaN weight
    gave NaN actions that lerobot-eval scored as failed episodes, a NaN delta_z a DP* that never rejects),
    and n_action_steps 0 trains, then fails at the first action."""
    for f in fields(config):
        value = getattr(config, f.name)
        values = value if isinstance(value, (list, tuple)) else [value]
        if any(isinstance(v, float) and not math.isfinite(v) for v in values):
            raise ValueError(
                f"`{f.name}` must be a finite number; got {value}. Set --policy.{f.name} to a "
                "number (its default is in `lerobot-train --policy.type=ccdp --help`)."
            )
    at_least = dict.fromkeys(POSITIVE_FIELDS, 1) | dict.fromkeys(NON_NEGATIVE_FIELDS, 0)
    small = {
        name: getattr(config, name)
        for name, low in at_least.items()
        if getattr(config, name) is not None and getattr(config, name) < low
    }
    small |= {"down_dims": config.down_dims} if not config.down_dims or min(config.down_dims) < 1 else {}
    if small:
        raise ValueError(
            f"{', '.join(f'`{k}`' for k in small)} must be >= 1 ({', '.join(NON_NEGATIVE_FIELDS)} >= 0, "
            f"`down_dims` non-empty); got {small}."
        )
    if config.num_inference_steps is not None and config.num_inference_steps > config.num_train_timesteps:
        raise ValueError(
            f"`num_inference_steps` ({config.num_inference_steps}) cannot exceed `num_train_timesteps` "
            f"({config.num_train_timesteps}): the reverse diffusion visits training timesteps."
        )
    steps = config.num_inference_steps or config.num_train_timesteps
    if config.w_z_from_step + (config.w_z_steps or 1) > steps:
        raise ValueError(
            f"`w_z_from_step` ({config.w_z_from_step}) + `w_z_steps` ({config.w_z_steps}) reach past the "
            f"{steps} reverse steps (numbered 0 to {steps - 1}): lower either."
        )
    if config.failure_guard_steps > steps:
        raise ValueError(
            f"`failure_guard_steps` ({config.failure_guard_steps}) exceeds the {steps} reverse steps: "
            "lower it."
        )


def _check_choices(config: CCDPConfig) -> None:
    """Every `Literal` field holds one of its values (a config file is read without draccus's decoding),
    and the noise scheduler is one diffusers has."""
    allowed = {f.name: get_args(f.type) for f in fields(config) if get_origin(f.type) is Literal}
    allowed["noise_scheduler_type"] = NOISE_SCHEDULERS
    for name, values in allowed.items():
        if getattr(config, name) not in values:
            raise ValueError(f"Unknown `{name}` {getattr(config, name)!r}; choose one of {list(values)}.")


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
    if config.image_features and config.recovery_head == "set_denoiser":
        raise ValueError(
            "recovery_head='set_denoiser' conditions on the state of synthesised rows, which carry no "
            "camera images yet: use --policy.recovery_head=unet with cameras."
        )
    if config.action_feature is None:
        raise ValueError(f"CCDP needs an {ACTION!r} output feature; the dataset has none.")
    if config.failure_feature == "final_state":
        source = config.input_features.get(config.failure_state_key)
        if source is None:
            raise ValueError(
                f"failure_feature='final_state' reads {config.failure_state_key!r}, which the dataset "
                f"lacks; choose --policy.failure_state_key among {sorted(config.input_features)}."
            )
        bad = [d for d in config.failure_state_dims if not 0 <= d < source.shape[0]]
        if bad:
            raise ValueError(
                f"`failure_state_dims` {bad} do not exist in {config.failure_state_key!r} "
                f"(shape {tuple(source.shape)})."
            )
    action_dim = config.action_feature.shape[-1]
    bad = [d for d in config.failure_action_dims if not 0 <= d < action_dim]
    if config.failure_feature == "action" and bad:
        raise ValueError(f"`failure_action_dims` {bad} do not exist in the {action_dim}-dim action.")


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
