"""How a batch becomes the frames the networks see (robot state, environment state, encoded cameras), and the
checks that turn a wrong input into an error naming the key and the fix rather than a NaN or a silent skip."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import torch
from lerobot.configs.types import NormalizationMode
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGE, OBS_IMAGES, OBS_STATE
from torch import Tensor, nn

from lerobot_ccdp.policy.configuration_ccdp import FAILURE_FEATURE_KEY, FAILURE_FLAG_KEY, CCDPConfig
from lerobot_ccdp.policy.image_encoder import ImageEncoder

if TYPE_CHECKING:  # the samplers import the composition, which needs nothing from here
    from lerobot_ccdp.policy.composition import CompositionWeights
    from lerobot_ccdp.policy.samplers import PlanRows

logger = logging.getLogger(__name__)

# Per normalisation mode: the stats whose difference is the spread LeRobot divides by (replaced by its eps
# where 0), and the normalised value of every frame of a dimension whose spread is 0 (x == min gives -1,
# x == mean gives 0).
_ZERO_SPREAD = {
    NormalizationMode.MIN_MAX: (("max", "min"), -1.0),
    NormalizationMode.QUANTILES: (("q99", "q01"), -1.0),
    NormalizationMode.QUANTILE10: (("q90", "q10"), -1.0),
    NormalizationMode.MEAN_STD: (("std",), 0.0),
}


# Largest |value| of a normalised input the policy acts on. Normalised demonstrations span [-1, 1] (min-max,
# quantiles) or have unit spread (mean-std), so a value beyond it lies a thousand spreads outside the data:
# a reading in other units (mm for m, 0-255 pixels for 0-1) or a failing sensor, not a state the policy
# learnt. Nothing is lost by refusing it: the networks saturate long before (on the reaching checkpoint the
# actions at 1e3 are within 2e-3 of those at 1e19), and from about 1e20 (by the weights) float32 overflows in
# the UNet's group norms and every action is NaN.
MAX_NORMALISED_INPUT = 1e3


def vector_keys(config: CCDPConfig) -> list[str]:
    """The vector inputs of a frame, in frame order."""
    return [OBS_STATE] + ([OBS_ENV_STATE] if config.env_state_feature else [])


def vector_names(config: CCDPConfig) -> list[str]:
    """The name of every vector dimension of a frame (`observation.state[0]`, ...), in frame order."""
    return [f"{key}[{i}]" for key in vector_keys(config) for i in range(config.input_features[key].shape[0])]


class ConstantInputs(nn.Module):
    """Vector input dimensions that held one value throughout the training data, kept at that value at run
    time.

    LeRobot's normaliser divides by the dimension's spread, replaced by 1e-8 where it is 0. A dimension
    constant in the demonstrations (the Bartender's `cup3_filled`: the demonstrator fills cup 3 last, so no
    frame shows it full) becomes 2e8 the first time it changes at run time, and every chunk planned from that
    frame is garbage. The dimension told the networks nothing in training, so it is held at the value it
    always had. The mask is a buffer: a checkpoint carries it, and checkpoints saved before it existed load
    with nothing held.
    """

    def __init__(self, config: CCDPConfig):
        super().__init__()
        dim = sum(config.input_features[key].shape[0] for key in vector_keys(config))
        self.register_buffer("held", torch.zeros(dim, dtype=torch.bool))
        self.register_buffer("value", torch.zeros(dim))
        self._names = vector_names(config)
        self._warned = False

    def fill(self, config: CCDPConfig, stats: dict) -> None:
        """Mark the dimensions whose training spread is 0 under their normalisation mode."""
        held, value = [], []
        for key in vector_keys(config):
            mode = config.normalization_mapping.get(
                config.input_features[key].type.value, NormalizationMode.IDENTITY
            )
            size, column = config.input_features[key].shape[0], stats.get(key, {})
            names, normalised = _ZERO_SPREAD.get(mode, ((), 0.0))
            if names and all(name in column for name in names):
                high, *low = (
                    torch.as_tensor(column[name], dtype=torch.float64).reshape(size) for name in names
                )
                held.append(high - sum(low) == 0)
            else:  # IDENTITY, or stats without the mode's entries: nothing is divided by a spread
                held.append(torch.zeros(size, dtype=torch.bool))
            value.append(torch.full((size,), normalised))
        self.held.copy_(torch.cat(held))
        self.value.copy_(torch.cat(value))

    def forward(self, vector: Tensor) -> Tensor:
        """`vector` (..., dim) with the held dimensions at their training value; the first change is logged
        once."""
        if not bool(self.held.any()):
            return vector
        if not self._warned:
            moved = (
                (((vector - self.value).abs() > 1e-3) & self.held).reshape(-1, vector.shape[-1]).any(dim=0)
            )
            if bool(moved.any()):
                self._warned = True
                names = [name for name, m in zip(self._names, moved, strict=True) if m]
                logger.warning(
                    "Input(s) %s never varied in the training data and now do: the policy holds them at "
                    "their training value, as it cannot have learned what they mean. Record demonstrations "
                    "that show them varying to let the policy use them.",
                    names,
                )
        return torch.where(self.held, self.value.to(vector.dtype), vector)


def observation_frames(
    config: CCDPConfig,
    images: ImageEncoder | None,
    batch: dict[str, Tensor],
    constant: ConstantInputs | None = None,
) -> Tensor:
    """Observation frames (B, [T,] frame_dim): robot state, environment state, then the encoded cameras.
    `batch` holds normalised inputs, one frame (B, ...) or a window (B, T, ...) each; `constant` holds the
    vector dimensions that never varied in training at their training value."""
    parts = []
    for key in vector_keys(config):
        value = _input(config, batch, key)
        expected = config.input_features[key].shape[0]
        if value.ndim < 2:
            raise ValueError(
                f"{key!r} has shape {tuple(value.shape)}; the policy takes a batch (B, {expected}), as "
                "LeRobot's preprocessor makes it. Add the batch dimension: value.unsqueeze(0)."
            )
        # the networks are float32: a robot's integer encoder counts (normalised by no preprocessor), or a
        # float64/float16 reading, made "mat1 and mat2 must have the same dtype" deep in the UNet
        value = value.float()
        if value.shape[-1] != expected:
            raise ValueError(
                f"{key!r} has {value.shape[-1]} dims on its last axis; the policy expects {expected}."
            )
        _refuse_non_finite(key, value)
        parts.append(value)
    vector = torch.cat(parts, dim=-1)
    if constant is not None:
        vector = constant(vector)
    _refuse_far_outside(vector, vector_names(config))
    parts = [vector]
    if images is not None:
        parts.append(images([_camera(config, batch, key, vector.shape[:-1]) for key in images.keys]))
    return torch.cat(parts, dim=-1)


def _refuse_non_finite(key: str, value: Tensor) -> None:
    if not bool(torch.isfinite(value).all()):
        raise ValueError(
            f"{key!r} contains NaN or inf; fix the dataset or env observation before calling the "
            "policy (a non-finite input would make that row's actions NaN)."
        )


def _refuse_far_outside(value: Tensor, names: list[str]) -> None:
    """Refuse a normalised input beyond MAX_NORMALISED_INPUT, naming the first such entry (`names` names the
    last axis, or holds one name for the whole tensor). Dimensions held by `ConstantInputs` are already at
    their training value."""
    far = value.abs() > MAX_NORMALISED_INPUT
    if not bool(far.any()):
        return
    where = far.nonzero()[0]
    name = names[int(where[-1])] if len(names) > 1 else names[0]
    raise ValueError(
        f"{name} is {value[tuple(where)].item():.4g} after normalisation, beyond the "
        f"+-{MAX_NORMALISED_INPUT:g} the policy acts on (normalised demonstrations lie within a few units "
        "of 0): no state it learnt from. Check the sensor, and this input's units against the training "
        "dataset's (metres, not millimetres; images as floats in [0, 1], not 0-255) and that it passes "
        "through the checkpoint's preprocessor. In a dataset, remove that frame or recompute the stats."
    )


def failure_flags(flag: Tensor, batch_size: int) -> Tensor:
    """`observation.failure` as one bool per row (B,). A flag is 0 (no failure) or 1 (the row's attempt just
    failed), shaped (B, 1) as LeRobot's env wrapper makes it, or (B,); anything else is refused rather than
    read: NaN is not "no failure", and a flag of another shape cannot be matched to the rows."""
    try:
        flag = torch.as_tensor(flag)
    except (TypeError, ValueError, RuntimeError):
        raise ValueError(
            f"{FAILURE_FLAG_KEY!r} is {flag!r}; it takes numbers, one flag per row (1: the attempt failed, "
            f"0: it did not), as a tensor of shape ({batch_size}, 1) or ({batch_size},)."
        ) from None
    if flag.numel() != batch_size or flag.ndim > 2 or (flag.ndim == 2 and flag.shape[1] != 1):
        raise ValueError(
            f"{FAILURE_FLAG_KEY!r} has shape {tuple(flag.shape)}; the policy takes one flag per row, shape "
            f"({batch_size}, 1) or ({batch_size},) for this batch of {batch_size}. Give each row's flag: "
            f"flag.reshape({batch_size}, 1)."
        )
    values = flag.reshape(batch_size)
    refused = ~((values == 0) | (values == 1))  # NaN is neither
    if bool(refused.any()):
        raise ValueError(
            f"{FAILURE_FLAG_KEY!r} holds {values[refused].tolist()} in row(s) "
            f"{refused.nonzero().flatten().tolist()}; a failure flag is 1 (the attempt failed) or 0 (it did "
            "not). Check the failure detector or env that sets it."
        )
    return values == 1


def refuse_unusable_weights(weight: Tensor) -> None:
    """The networks act in float32 on a device that holds values; `weight` is a tensor that moves and casts
    with them (a buffer: test models of exact networks have no parameters). After
    `policy.to("meta")` the first action failed in "Tensor.item() cannot be called on meta tensors", after
    `policy.half()` in "mat1 and mat2 must have the same dtype"."""
    if weight.is_meta:
        raise RuntimeError(
            "The policy's weights are on the meta device, which holds shapes but no values "
            "(policy.to('meta'), or a model made under torch.device('meta')): nothing can be computed. "
            "Load it with CCDPPolicy.from_pretrained(path)."
        )
    if weight.dtype != torch.float32:
        raise RuntimeError(
            f"The policy's weights are {weight.dtype} (policy.half() or policy.to(dtype)); ccdp acts in "
            "float32, as it was trained. Call policy.float()."
        )


def refuse_unfit_noise(noise: Tensor | None, shape: tuple[int, ...]) -> None:
    """The caller's initial noise must be one finite float32 chunk per row, of `shape` (B, horizon, A), within
    +-MAX_NORMALISED_INPUT: it starts every reverse diffusion, and NaN in it made NaN actions, another dtype
    a dtype error deep in the UNet, and 1e30 an overflow blamed on the weights."""
    if noise is None:
        return
    if not isinstance(noise, Tensor) or tuple(noise.shape) != shape or noise.dtype != torch.float32:
        got = (
            f"shape {tuple(noise.shape)} of {noise.dtype}"
            if isinstance(noise, Tensor)
            else type(noise).__name__
        )
        raise ValueError(
            f"noise= got {got}; it is the initial noise of one chunk per row, a float32 tensor of shape "
            f"{shape} (batch, horizon, action dim), e.g. torch.randn(shape). Leave it out to draw it."
        )
    if not bool(torch.isfinite(noise).all()):
        raise ValueError("noise= holds NaN or inf: draw it with torch.randn, or leave it out.")
    if bool((noise.abs() > MAX_NORMALISED_INPUT).any()):
        raise ValueError(
            f"noise= holds {noise.abs().max().item():.3g}, beyond +-{MAX_NORMALISED_INPUT:g}: the initial "
            "noise is standard normal (torch.randn), within +-6 in practice. Draw it with torch.randn, or "
            "leave it out."
        )


def reported_failure_features(z: object, rows: int, dim: int, feature: str, device: torch.device) -> Tensor:
    """`report_failure(z=...)` as a float32 tensor (rows, dim): one finite normalised z per failed row, within
    +-MAX_NORMALISED_INPUT like every normalised input (a z of 1e30 was taken, and overflowed in the recovery
    head). Anything else is refused before any failure is recorded."""
    taken = f"it takes one normalised z per failed row, ({rows}, {dim}) here ({feature} feature)"
    try:
        value = torch.as_tensor(z, dtype=torch.float32, device=device)
    except (TypeError, ValueError, RuntimeError):
        raise ValueError(
            f"report_failure(z={z!r}) got a {type(z).__name__}; {taken}, as numbers. Leave z out to use the "
            "attempt's own failure feature."
        ) from None
    if value.shape[-1:] != (dim,) or value.numel() != rows * dim:
        raise ValueError(
            f"report_failure(z=...) got shape {tuple(value.shape)}; {taken}. Leave z out to use the "
            "attempt's own failure feature."
        )
    if not bool(torch.isfinite(value).all()):
        raise ValueError(
            f"report_failure(z=...) holds NaN or inf ({value.tolist()}): a failure feature must be finite. "
            "Check the detector that computed it, or leave z out to use the attempt's own."
        )
    if bool((value.abs() > MAX_NORMALISED_INPUT).any()):
        raise ValueError(
            f"report_failure(z=...) holds {value.abs().max().item():.4g}, beyond the "
            f"+-{MAX_NORMALISED_INPUT:g} the policy acts on: z is normalised (as the preprocessor normalises "
            "the feature it describes), so failures lie near 0: normalise it, or leave z out."
        )
    return value.reshape(rows, dim)


def refuse_unknown_cameras(config: CCDPConfig, batch: dict[str, Tensor]) -> None:
    """A camera dataset given to a checkpoint that never saw those cameras would silently train without
    them."""
    unknown = [k for k in _camera_keys(batch) if k not in config.image_features]
    if unknown:
        raise ValueError(
            f"The dataset has cameras {unknown} that this policy does not encode (its inputs: "
            f"{_inputs(config)}). To use them, train a new base stage on this dataset (--policy.type=ccdp, "
            "no --policy.path); to train without them, use a dataset without those cameras."
        )


def refuse_non_finite_stats(config: CCDPConfig, stats: dict) -> None:
    """NaN or inf in a dataset column makes its stats non-finite, and training would run to a NaN checkpoint
    (LeRobot trains on, logging loss:nan): stop before the first step, naming the column."""
    for key in [*config.input_features, *config.output_features]:
        for name, value in stats.get(key, {}).items():
            if not torch.isfinite(torch.as_tensor(value, dtype=torch.float64)).all():
                raise ValueError(
                    f"The dataset's {name} of {key!r} is not finite: the dataset holds NaN or inf in "
                    f"{key!r}. Remove or re-record those frames, then recompute its stats."
                )


def refuse_non_finite_batch(batch: dict[str, Tensor], otherwise: str) -> None:
    """Raise for a batch that made a non-finite loss or frame: a ValueError naming its NaN or inf keys, else
    FloatingPointError(`otherwise`). The policy must neither train on them (LeRobot trains on to a NaN
    checkpoint and exits 0) nor act on them (NaN actions sent to the robot)."""
    bad = sorted(
        key
        for key, value in batch.items()
        if isinstance(value, Tensor) and value.is_floating_point() and not bool(torch.isfinite(value).all())
    )
    if not bad:
        raise FloatingPointError(otherwise)
    raise ValueError(
        f"The batch holds NaN or inf in {bad}. In a dataset, remove or re-record those frames and "
        "recompute its stats; on a robot or env, check the sensor or observation that produced them."
    )


def _input(config: CCDPConfig, batch: dict[str, Tensor], key: str) -> Tensor:
    if key not in batch:
        cameras = _camera_keys(batch)
        hint = ""
        if cameras and key not in config.image_features:
            hint = (
                f" The batch holds cameras {cameras} instead: this checkpoint was trained on other "
                "observations (for a ccdp task, evaluate it with the --env.obs_type it was trained with)."
            )
        raise KeyError(
            f"CCDP needs {key!r} in every batch (it was trained with inputs {_inputs(config)}); got keys "
            f"{sorted(batch)}.{hint}"
        )
    return batch[key]


def _camera(config: CCDPConfig, batch: dict[str, Tensor], key: str, lead: torch.Size) -> Tensor:
    """One camera's images (*lead, C, H, W), checked against the shape the encoder was built for."""
    image = _input(config, batch, key)
    if image.ndim == len(lead) + 2 and len(lead) > 1 and lead[-1] == 1:
        image = image.unsqueeze(-4)  # LeRobotDataset squeezes a one-frame window of video to (B, C, H, W)
    expected = tuple(config.image_features[key].shape)
    if tuple(image.shape[-3:]) != expected or image.shape[:-3] != lead:
        raise ValueError(
            f"{key!r} has shape {tuple(image.shape)}; the policy expects {(*lead, *expected)} (channels, "
            "height, width as in its training data). Render or resize this camera to that size (for a ccdp "
            "task: --env.observation_height/--env.observation_width), or train on images of this size."
        )
    if not image.is_floating_point():  # the encoder's convolution failed: "expected scalar type Byte"
        raise ValueError(
            f"{key!r} holds {image.dtype} values; the policy takes float images in [0, 1], as LeRobot's "
            "datasets and envs give them (a uint8 camera frame is 0-255: image.float() / 255)."
        )
    image = image.float()  # a float64 or float16 image failed in the encoder's float32 convolution
    _refuse_non_finite(key, image)
    _refuse_far_outside(image, [repr(key)])
    return image


def _inputs(config: CCDPConfig) -> list[str]:
    return sorted(k for k in config.input_features if k != FAILURE_FEATURE_KEY)


def _camera_keys(batch: dict[str, Tensor]) -> list[str]:
    """The batch's camera entries (`observation.image` or `observation.images.<name>`, not their pad
    masks)."""
    return sorted(
        k for k in batch if (k.startswith(f"{OBS_IMAGES}.") or k == OBS_IMAGE) and not k.endswith("_is_pad")
    )


def refuse_non_finite_plan(
    tensors: dict[str, Tensor],
    weights: CompositionWeights,
    rows: Tensor,
    chunks: Tensor,
    plan: PlanRows,
    mode: str,
) -> None:
    """Non-finite actions are never returned: name what made them (damaged tensors, non-finite
    failures, or settings that overflow eq. (4))."""
    bad = rows.nonzero().flatten()[~torch.isfinite(chunks).flatten(start_dim=1).all(dim=1)].tolist()
    damaged = [
        name
        for name, tensor in tensors.items()
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all())
    ]
    settings = f"w_s={weights.w_s}, w_h={weights.w_h}, w_z={weights.w_z}"
    if damaged:
        cause = (
            f"the policy's tensors {damaged[:3]}{' ...' if len(damaged) > 3 else ''} hold NaN or inf: "
            "load the checkpoint again from its files, or train it anew"
        )
    elif not bool(torch.isfinite(plan.z).all()):
        cause = "the rows' recorded failure features z hold NaN or inf: reset() and report finite ones"
    else:
        largest = float(torch.cat([plan.state, plan.history], dim=-1).abs().max())
        cause = (
            f"its tensors and inputs are finite (the largest normalised input {largest:.3g}), so the "
            f"networks or eq. (4) overflowed at the settings {settings}: use finite weights near the "
            "defaults (w_z 5, w_h 0), and inputs within the training data's range"
        )
    raise FloatingPointError(
        f"The {mode} sampler made NaN or inf actions for row(s) {bad}; none were returned. Cause: {cause}."
    )


def demonstration_windows(
    config: CCDPConfig, frames: Tensor, batch: dict[str, Tensor]
) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
    """A demonstration batch as the base sees it: state condition, history condition, the chunk to denoise
    and the chunk's padding flags (or None), from its frames (B, T, frame_dim) and its actions."""
    cfg = config
    windows = (cfg.history_length + cfg.n_obs_steps, cfg.history_length + cfg.horizon)
    if frames.ndim != 3 or batch[ACTION].ndim != 3 or (frames.shape[1], batch[ACTION].shape[1]) != windows:
        raise ValueError(
            f"This stage expects observation windows (B, {cfg.history_length + cfg.n_obs_steps}, D) and "
            f"action chunks (B, {cfg.history_length + cfg.horizon}, A); got {tuple(frames.shape)} and "
            f"{tuple(batch[ACTION].shape)}. Load the dataset with the policy's delta timestamps "
            "(lerobot-train does)."
        )
    h = cfg.history_length
    actions, pad = batch[ACTION], batch.get("action_is_pad")
    past_actions = actions[:, :h]
    if pad is not None:
        past_actions = past_actions * ~pad[:, :h, None]  # no action was taken before the episode began
    history = torch.cat([frames[:, :h].flatten(start_dim=1), past_actions.flatten(start_dim=1)], dim=-1)
    return frames[:, h:].flatten(start_dim=1), history, actions[:, h:], pad
