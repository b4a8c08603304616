"""What a recovery head is, and the table that names them (`recovery_head`).

A head is one module under `policy/heads/`: its network (built into `model.recovery`, so its weights sit under
`model.recovery.*` in a checkpoint), the data it trains on, its training loss, its noise estimate at sampling
time when a row has failures, and the settings only it reads. `CCDPModel` holds the base loss and the reverse
loop and asks its head (`model.head`) for the rest; nothing outside this folder compares `recovery_head` with
a name. A config that names no head ("auto") gets the default for its inputs (`head_of`), named in the config
once its features are known (`name_default_head`, at `CCDPConfig.validate_features`). The head's methods reach
the network through `model.recovery`, so a test may put another network there.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, ClassVar, Literal

from torch import Tensor, nn

if TYPE_CHECKING:  # the model module imports the heads
    from lerobot_ccdp.policy.composition import CompositionWeights
    from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
    from lerobot_ccdp.policy.modeling_ccdp import CCDPModel

# What a head's recovery stage reads: the demonstrations themselves (windows, as the base), the recovery pairs
# of a synthesised dataset (chunk, z), or the base's own samples with their state and siblings.
TrainingData = Literal["demonstrations", "recovery_pairs", "base_samples"]
# The noise estimate of one reverse step: (noisy sample (R, horizon, A), timestep) -> eps (R, horizon, A).
Estimate = Callable[[Tensor, int], Tensor]


class RecoveryHead:
    """A recovery head: which network it builds and what the model asks of it."""

    name: ClassVar[str]
    network: ClassVar[type[nn.Module]]  # built with the config: `network(config)`
    training_data: ClassVar[TrainingData]
    # Config fields only this head reads; set away from their defaults with another head, they are refused.
    own_settings: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def check_config(cls, config: CCDPConfig) -> None:
        """Refuse settings this head cannot run with (called with the other config checks)."""

    @classmethod
    def describe(cls, settings: Mapping[str, Any]) -> str:
        """How the failures enter eq. (4) at these config settings (a checkpoint's config.json, flags
        applied), as the benchmark's report names the form that ran."""
        raise NotImplementedError

    @classmethod
    def unet_condition(cls, step: int, base_condition: int, z_size: int) -> int | None:
        """The global condition size of the head's diffusion UNet, for `config_checks.memory_estimate`
        (a lower bound; None: the head has no UNet). `base_condition` is the base UNet's."""
        return None

    def loss(self, model: CCDPModel, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """The recovery stage's loss on a batch of `training_data`, and what to log beside it."""
        raise NotImplementedError

    def estimate(
        self,
        model: CCDPModel,
        weights: CompositionWeights,
        state: Tensor,
        history: Tensor,
        z: Tensor,
        z_mask: Tensor,
        timesteps: list[int],
    ) -> Estimate:
        """The noise estimate of every reverse step for rows remembering failures (`z` (R, N, z_dim) with
        `z_mask` (R, N), N > 0; rows may hold none), given the reverse loop's `timesteps`."""
        raise NotImplementedError


HEADS: dict[str, type[RecoveryHead]] = {}


def register_head(name: str) -> Callable[[type[RecoveryHead]], type[RecoveryHead]]:
    """Class decorator: the head `--policy.recovery_head=<name>` builds."""

    def register(cls: type[RecoveryHead]) -> type[RecoveryHead]:
        cls.name = name
        HEADS[name] = cls
        return cls

    return register


def head_class(name: str) -> type[RecoveryHead]:
    if name not in HEADS:
        raise ValueError(f"recovery_head={name!r} names no head; the heads are {sorted(HEADS)}.")
    return HEADS[name]


# `recovery_head="auto"` (the default) names no head: it gets the set denoiser, which every benchmark table
# measured, where it runs (its `check_config`: state inputs, one observation frame), else the paper's eps_z
# heads, which run with every input (cameras, several observation frames).
AUTO, DEFAULT_HEAD, FALLBACK_HEAD = "auto", "set_denoiser", "unet"


def head_of(config: CCDPConfig) -> type[RecoveryHead]:
    """The head `config.recovery_head` names, or for "auto" the default for the inputs the config knows so
    far; `name_default_head` fixes it once they are all known."""
    if config.recovery_head != AUTO:
        return head_class(config.recovery_head)
    try:
        HEADS[DEFAULT_HEAD].check_config(config)
    except ValueError:
        return HEADS[FALLBACK_HEAD]
    return HEADS[DEFAULT_HEAD]


def name_default_head(config: CCDPConfig) -> None:
    """Name the default head in a config that says "auto", once its input features are known (LeRobot sets
    them from the dataset or env before `validate_features`), so that the checkpoint's config.json, and
    every stage that loads it (synthesis, the recovery stage, lerobot-eval), holds the head it was built
    with."""
    config.recovery_head = head_of(config).name


def make_head(config: CCDPConfig) -> RecoveryHead:
    """The head the config names (`head_of`)."""
    return head_of(config)()


def refuse_settings_of_other_heads(config: CCDPConfig) -> None:
    """A field only another head reads, set away from its default, would do nothing: refused with the fix.
    A value that turns the setting off (None, 0, False) sets nothing: a config.json saved when `w_z_steps`
    defaulted to None, or the guard to 0 steps, holds it for every head."""
    own = head_of(config)
    for owner in HEADS.values():
        for field in set(owner.own_settings) - set(own.own_settings):
            value, default = getattr(config, field), type(config).__dataclass_fields__[field].default
            if value and value != default:
                raise ValueError(
                    f"`{field}` ({value}) is a setting of the {owner.name!r} head; the {own.name!r} head "
                    f"reads none. Remove --policy.{field}{_or_use(owner, config)}."
                )


def _or_use(owner: type[RecoveryHead], config: CCDPConfig) -> str:
    """The other fix, naming the head that reads the setting, where that head can serve this config (the set
    denoiser cannot with cameras: suggesting it would only lead to its own refusal)."""
    try:
        owner.check_config(config)
    except ValueError as reason:
        return f" (the {owner.name!r} head cannot serve this config: {reason})"
    return f" or use --policy.recovery_head={owner.name}"
