"""The `unet` head: eps_z(a, z, k), one term per remembered failure in eq. (4) (`composition.compose_eps`),
trained on the recovery pairs (chunk, z) of a synthesised dataset (lerobot-ccdp-synthesize, eq. 5-7)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import torch
import torch.nn.functional as F  # noqa: N812
from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d
from lerobot.utils.constants import ACTION
from torch import Tensor, nn

from lerobot_ccdp.policy.base_denoiser import base_estimates
from lerobot_ccdp.policy.composition import (
    POLICY_Z_REFERENCE,
    CompositionWeights,
    compose_eps,
    recovery_conditions,
)
from lerobot_ccdp.policy.configuration_ccdp import FAILURE_FEATURE_KEY, CCDPConfig
from lerobot_ccdp.policy.heads.registry import Estimate, RecoveryHead, register_head
from lerobot_ccdp.policy.small_batch_convolutions import with_small_batch_convolutions

if TYPE_CHECKING:  # the model module imports the heads
    from lerobot_ccdp.policy.modeling_ccdp import CCDPModel

# Condition dropout of z while training: the dropped rows train the head's eps_z_null.
P_DROP_FAILURE = 0.1


class RecoveryUnet(nn.Module):
    """eps_z(a, z, k): LeRobot's diffusion UNet with z as its global condition (no state, as in eq. 4).

    It learns which modes of the demonstrated chunks are absent given z far better than an MLP over the
    flattened chunk; all remembered failures of a step are evaluated in one batched call.
    """

    def __init__(self, config: CCDPConfig):
        super().__init__()
        self.unet = with_small_batch_convolutions(
            DiffusionConditionalUnet1d(config, global_cond_dim=config.failure_feature_dim + 1)
        )

    def forward(self, noisy: Tensor, timestep: Tensor, z: Tensor, keep_z: Tensor) -> Tensor:
        """noisy (R, horizon, A); timestep (R,); z (R, z_dim); keep_z (R, 1) -> predicted noise
        (R, horizon, A). A dropped z (keep 0) is zeroed, so the head learns eps_z_null on the same data."""
        return self.unet(noisy, timestep, global_cond=torch.cat([z * keep_z, keep_z], dim=-1))


@register_head("unet")
class UnetHead(RecoveryHead):
    network = RecoveryUnet
    training_data = "recovery_pairs"

    @classmethod
    def describe(cls, settings: Mapping[str, Any]) -> str:
        return f"w_h {settings['w_h']:g}, w_z {settings['w_z']:g} against {POLICY_Z_REFERENCE}"

    @classmethod
    def unet_condition(cls, step: int, base_condition: int, z_size: int) -> int | None:
        return step + z_size + 1

    def loss(self, model: CCDPModel, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Noise regression of eps_z(a, z) on the recovery rows, z dropped on P_DROP_FAILURE of them."""
        cfg = model.config
        z = batch.get(FAILURE_FEATURE_KEY)
        if z is not None and z.ndim == 1 and cfg.failure_feature_dim == 1:
            # LeRobotDataset stores a feature of shape (1,) as a scalar column: a batch is (B,)
            z = z[:, None]
        if z is None or z.shape[-1] != cfg.failure_feature_dim:
            got = "no such column" if z is None else f"shape {tuple(z.shape)}"
            raise ValueError(
                f"The recovery stage trains on a recovery dataset with {FAILURE_FEATURE_KEY!r} of size "
                f"{cfg.failure_feature_dim} ({cfg.failure_feature} feature); got {got}. Make one with "
                "lerobot-ccdp-synthesize using the same failure feature."
            )
        chunk = batch[ACTION]
        if chunk.ndim != 3 or chunk.shape[1] != cfg.horizon:
            raise ValueError(
                f"Recovery rows hold whole chunks (B, {cfg.horizon}, A) under {ACTION!r}; got "
                f"{tuple(chunk.shape)}."
            )
        model.recovery_trained.fill_(True)
        noise, timesteps, noisy = model.noised(chunk)
        keep_z = (torch.rand(chunk.shape[0], 1, device=chunk.device) >= P_DROP_FAILURE).to(z.dtype)
        return F.mse_loss(model.recovery(noisy, timesteps, z, keep_z), noise), {}

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
        """eq. (4) with one eps_z term per failure slot (`compose_eps`), against eps_a or eps_z_null."""
        n = z.shape[1]
        base = base_estimates(model.base, weights.base_terms(z_mask.sum(dim=1)), state, history)
        z_rows, keep_z = recovery_conditions(z, weights.measures_against_z_null)

        def estimate(sample: Tensor, t: int) -> Tensor:
            by_term = base(sample, t)
            eps_z, eps_z_null = _recovery_terms(model.recovery, sample, t, z_rows, keep_z, n)
            return compose_eps(
                weights, by_term.get("a"), by_term.get("s"), by_term.get("h"), eps_z, z_mask, eps_z_null
            )

        return estimate


def _recovery_terms(
    recovery: nn.Module, sample: Tensor, t: int, z_rows: Tensor, keep_z: Tensor, n: int
) -> tuple[Tensor, Tensor | None]:
    """eps_z(z_i) for every failure slot (R, N, horizon, A) and, when `z_rows` ends with the z-dropped rows,
    eps_z_null (R, horizon, A): one recovery call for all of them."""
    r, chunk = sample.shape[0], sample.shape[1:]
    noisy = sample[:, None].expand(r, n, *chunk).reshape(r * n, *chunk)
    null_row = z_rows.shape[0] > r * n
    if null_row:
        noisy = torch.cat([noisy, sample])
    step = torch.full((noisy.shape[0],), t, dtype=torch.long, device=sample.device)
    eps = recovery(noisy, step, z_rows, keep_z)
    return eps[: r * n].view(r, n, *chunk), (eps[r * n :] if null_row else None)
