"""The `classifier` head: a noisy-chunk classifier of "repeats a failure of F", trained on the demonstrations,
whose gradient guides eps_s away from what failed (`composition.guide_away_from_failures`). Its network and
set embedding are also the set denoiser's guard (`heads/set_denoiser.py`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import torch
import torch.nn.functional as F  # noqa: N812
from lerobot.policies.diffusion.modeling_diffusion import DiffusionSinusoidalPosEmb
from torch import Tensor, nn

from lerobot_ccdp.policy.base_denoiser import P_DROP_STATE
from lerobot_ccdp.policy.composition import CompositionWeights, guide_away_from_failures, log_no_repeat
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig, z_fourier_octaves_of
from lerobot_ccdp.policy.failure_buffer import distinct_failures, draw_failure_sets
from lerobot_ccdp.policy.heads.registry import Estimate, RecoveryHead, register_head

if TYPE_CHECKING:  # the model module imports the heads
    from lerobot_ccdp.policy.modeling_ccdp import CCDPModel

# Width of the failure set's embedding and of the classifier's MLP, and the classifier's residual blocks.
HIDDEN_WIDTH = 128
CLASSIFIER_BLOCKS = 3
# Failures drawn for one training row (1 to this many).
FAILURE_SET_TRAIN_SIZE = 3


class FailureSetClassifier(nn.Module):
    """logit of P(a_0 repeats a failure in F | a_t, s, k): a noisy-chunk classifier for the whole failure set
    F.

    Trained on the demonstrations with F drawn independently of each row (the label says whether the row's
    own z lies within delta_z of a failure in F; `ClassifierHead.loss`), its gradient turns eps_s into the
    noise estimate of p_s restricted to the chunks outside F (`composition.guide_away_from_failures`). A
    residual MLP over the flattened chunk, FiLM-conditioned on the diffusion step, the state (droppable) and
    the set's embedding (a max over an MLP of each z_i, so neither F's order nor a repeated failure changes
    it).
    """

    def __init__(self, config: CCDPConfig):
        super().__init__()
        width, chunk = HIDDEN_WIDTH, config.horizon * config.action_dim
        self.step_embedding = nn.Sequential(
            DiffusionSinusoidalPosEmb(config.diffusion_step_embed_dim),
            nn.Linear(config.diffusion_step_embed_dim, width),
            nn.Mish(),
        )
        self.state_embedding = nn.Linear(config.n_obs_steps * config.frame_dim + 1, width)
        self.set_embedding = set_embedding(config, width)
        self.inp = nn.Linear(chunk, width)
        self.blocks = nn.ModuleList(_FiLMBlock(width) for _ in range(CLASSIFIER_BLOCKS))
        self.logit = nn.Linear(width, 1)

    def forward(
        self,
        noisy: Tensor,
        timestep: Tensor,
        state: Tensor,
        z: Tensor,
        z_mask: Tensor,
        keep_s: Tensor | None = None,
    ) -> Tensor:
        """noisy (R, horizon, A); state (R, state_cond_dim); z (R, N, z_dim) with z_mask (R, N), at least one
        failure per row; keep_s (R, 1) drops the state of some rows while training (default: kept) -> logits
        (R,)."""
        keep_s = state.new_ones(state.shape[0], 1) if keep_s is None else keep_s
        per_failure = self.set_embedding(z).masked_fill(~z_mask[..., None], float("-inf"))
        cond = (
            self.step_embedding(timestep)
            + self.state_embedding(torch.cat([state * keep_s, keep_s], dim=-1))
            + per_failure.amax(dim=1)
        )
        h = self.inp(noisy.flatten(start_dim=1))
        for block in self.blocks:
            h = block(h, cond)
        return self.logit(h).squeeze(-1)


@register_head("classifier")
class ClassifierHead(RecoveryHead):
    network = FailureSetClassifier
    training_data = "demonstrations"

    @classmethod
    def describe(cls, settings: Mapping[str, Any]) -> str:
        return f"w_h {settings['w_h']:g}; failures by classifier guidance, w_z {settings['w_z']:g}"

    def loss(self, model: CCDPModel, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """The failure-set classifier on the demonstrated chunks. Each row gets a failure set F of 1 to
        FAILURE_SET_TRAIN_SIZE z drawn from other rows (so F is independent of the row's own chunk) and is a
        repeat when its own z lies within delta_z of a failure in F; the classifier learns P(repeat | a_t, s)
        with the base's noise schedule. The state is dropped as in the base (`classifier_loss`)."""
        state, _, chunk, _ = model.windows(batch)
        if chunk.shape[0] < 2:
            raise ValueError(
                "The classifier draws each row's failures from the other rows: use --batch_size >= 2."
            )
        model.recovery_trained.fill_(True)
        z_set, z_mask, repeats = draw_failure_sets(
            model.feature.from_chunk(chunk, model.outcomes), FAILURE_SET_TRAIN_SIZE, model.config.delta_z
        )
        _, timesteps, noisy = model.noised(chunk)
        return classifier_loss(model.recovery, noisy, timesteps, state, z_set, z_mask, repeats), {}

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
        """eq. (4) without failure terms, guided away from F by the classifier's gradient in the rows with
        failures (`guide_away_from_failures` at w_z)."""
        composed_without_failures = model.estimate_without_failures(weights, state, history)
        failed = z_mask.any(dim=1)

        def estimate(sample: Tensor, t: int) -> Tensor:
            composed = composed_without_failures(sample, t)
            if failed.any():
                step = torch.full((int(failed.sum()),), t, dtype=torch.long, device=sample.device)
                gradient = torch.zeros_like(sample)
                gradient[failed] = no_repeat_gradient(
                    model.recovery,
                    sample[failed],
                    step,
                    state[failed],
                    z[failed],
                    z_mask[failed],
                    model.config.delta_z,
                )
                alpha_bar = model.noise_scheduler.alphas_cumprod[t].to(sample.device)
                composed = guide_away_from_failures(composed, gradient, alpha_bar, weights.w_z)
            return composed

        return estimate


def classifier_loss(
    classifier: nn.Module,
    noisy: Tensor,
    timesteps: Tensor,
    state: Tensor,
    z_set: Tensor,
    z_mask: Tensor,
    repeats: Tensor,
) -> Tensor:
    """Binary cross-entropy of a failure-set classifier's logit of "this row repeats a failure of F" on noisy
    rows. The state is dropped as in the base: where it already names the option, a state-conditioned row says
    little about F, while state-free rows tie F to the chunks it excludes, in the same network."""
    keep_s = (torch.rand(noisy.shape[0], 1, device=noisy.device) >= P_DROP_STATE).to(noisy.dtype)
    logits = classifier(noisy, timesteps, state, z_set, z_mask, keep_s)
    return F.binary_cross_entropy_with_logits(logits, repeats.to(logits.dtype))


def no_repeat_gradient(
    classifier: nn.Module,
    sample: Tensor,
    step: Tensor,
    state: Tensor,
    z: Tensor,
    z_mask: Tensor,
    delta_z: float,
) -> Tensor:
    """grad_{a_t} log P(a_0 outside F | a_t, s) from a failure-set classifier (this head's network or the set
    denoiser's guard). LeRobot samples under torch.inference_mode(), where no gradient exists: the inputs are
    copied into ordinary tensors first."""
    with torch.inference_mode(False), torch.enable_grad():
        noisy = sample.clone().requires_grad_(True)
        step, state, z, z_mask = step.clone(), state.clone(), z.clone(), z_mask.clone()
        rows, n = z_mask.shape  # one classifier call for every (row, failure) pair
        logits = classifier(
            noisy.repeat_interleave(n, dim=0),
            step.repeat_interleave(n, dim=0),
            state.repeat_interleave(n, dim=0),
            z.reshape(rows * n, 1, -1),
            z_mask.new_ones(rows * n, 1),
        )
        log_outside = log_no_repeat(logits.view(rows, n), distinct_failures(z, z_mask, delta_z))
        (gradient,) = torch.autograd.grad(log_outside.sum(), noisy)
    return gradient


def set_embedding(config: CCDPConfig, width: int) -> nn.Module:
    """An MLP of one failure's z (its Fourier features with `z_fourier_octaves`), maxed over F by the
    heads. With octaves the Linear layers sit at other indices than without, so a base checkpoint's untrained
    head of the other kind loads as missing and unexpected keys, never as a size mismatch."""
    dim = config.failure_feature_dim
    octaves = z_fourier_octaves_of(config)
    if not octaves:
        return nn.Sequential(nn.Linear(dim, width), nn.Mish(), nn.Linear(width, width))
    features = FourierFeatures(octaves)
    return nn.Sequential(
        features, nn.Linear(dim * (1 + 2 * features.octaves), width), nn.Mish(), nn.Linear(width, width)
    )


class FourierFeatures(nn.Module):
    """z -> [z, sin(2^k pi z), cos(2^k pi z)] for k < octaves: a continuous z's nearby outcomes made far apart
    in the features the set embedding reads."""

    def __init__(self, octaves: int):
        super().__init__()
        self.octaves = octaves
        self.register_buffer("scales", torch.pi * 2.0 ** torch.arange(octaves), persistent=False)

    def forward(self, z: Tensor) -> Tensor:
        angles = (z[..., None] * self.scales).flatten(start_dim=-2)
        return torch.cat([z, angles.sin(), angles.cos()], dim=-1)


class _FiLMBlock(nn.Module):
    def __init__(self, width: int):
        super().__init__()
        self.norm = nn.LayerNorm(width)
        self.film = nn.Linear(width, 2 * width)
        self.mlp = nn.Sequential(nn.Linear(width, width), nn.Mish(), nn.Linear(width, width))

    def forward(self, h: Tensor, cond: Tensor) -> Tensor:
        scale, shift = self.film(cond).chunk(2, dim=-1)
        return h + self.mlp(self.norm(h) * (1 + scale) + shift)
