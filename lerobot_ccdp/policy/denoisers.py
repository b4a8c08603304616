"""The networks: the base UNet (eps_a, eps_s, eps_h) and the recovery head (eps_z, a failure-set classifier,
or the failure-set denoiser eps_{s,F})."""

import torch
from lerobot.policies.diffusion.modeling_diffusion import (
    DiffusionConditionalUnet1d,
    DiffusionSinusoidalPosEmb,
)
from torch import Tensor, nn

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.small_batch_convolutions import with_small_batch_convolutions

# Width of the failure set's embedding and of the classifier's MLP, and the classifier's residual blocks.
HIDDEN_WIDTH = 128
CLASSIFIER_BLOCKS = 3


class BaseDenoiser(nn.Module):
    """LeRobot's diffusion UNet with two droppable conditions, so one network gives eps_a, eps_s and eps_h.

    The global condition is [state * keep_s, keep_s, history * keep_h, keep_h]: a dropped condition is zeroed
    and its keep flag tells the network it is absent (condition dropout, as in classifier-free guidance).
    """

    def __init__(self, config: CCDPConfig):
        super().__init__()
        self.state_cond_dim = config.n_obs_steps * config.frame_dim
        self.history_cond_dim = config.history_length * (config.frame_dim + config.action_dim)
        self.unet = with_small_batch_convolutions(
            DiffusionConditionalUnet1d(
                config, global_cond_dim=self.state_cond_dim + self.history_cond_dim + 2
            )
        )

    def forward(
        self, noisy: Tensor, timestep: Tensor, state: Tensor, keep_s: Tensor, history: Tensor, keep_h: Tensor
    ) -> Tensor:
        """noisy (R, horizon, A); state (R, state_cond_dim); history (R, history_cond_dim); keep_* (R, 1)."""
        cond = torch.cat([state * keep_s, keep_s, history * keep_h, keep_h], dim=-1)
        return self.unet(noisy, timestep, global_cond=cond)


def make_recovery_denoiser(config: CCDPConfig) -> nn.Module:
    """The recovery network `config.recovery_head` names: eps_z(a, z, k) per failure, or the failure-set
    classifier."""
    heads = {"unet": RecoveryUnet, "classifier": FailureSetClassifier, "set_denoiser": FailureSetDenoiser}
    return heads[config.recovery_head](config)


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
        (R, horizon, A)."""
        return self.unet(noisy, timestep, global_cond=_z_condition(z, keep_z))


class FailureSetClassifier(nn.Module):
    """logit of P(a_0 repeats a failure in F | a_t, s, k): a noisy-chunk classifier for the whole failure set
    F.

    Trained on the demonstrations with F drawn independently of each row (the label says whether the row's own
    z lies within delta_z of a failure in F; `CCDPModel._failure_set_loss`), its gradient turns eps_s into the
    noise estimate of p_s restricted to the chunks outside F (`composition.guide_away_from_failures`). A
    residual MLP over the flattened chunk, FiLM-conditioned on the diffusion step, the state (droppable) and
    the set's embedding (a max over an MLP of each z_i, so neither F's order nor a repeated failure changes
    it).
    """

    def __init__(self, config: CCDPConfig):
        super().__init__()
        width, chunk = HIDDEN_WIDTH, config.horizon * config.action_dim
        self.step_embedding = _step_embedding(config, width)
        self.state_embedding = nn.Linear(config.n_obs_steps * config.frame_dim + 1, width)
        self.set_embedding = _set_embedding(config, width)
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


class FailureSetDenoiser(nn.Module):
    """eps_{s,F}(a_t, k): the noise estimate of p_s restricted to the chunks whose outcome lies outside the
    failure set F.

    A copy of the base UNet whose global condition is the base's own with the state kept and the history
    dropped, followed by an embedding of F (a max over an MLP of each z_i, so neither F's order nor a repeated
    failure changes it). `start_from` copies the base with the set's condition weights zeroed, so training
    starts from eps_s exactly. Trained on chunks the base samples at option starts and along the demos, with F
    drawn independently of each row and the rows whose own outcome lies in F left out
    (`CCDPModel._set_denoiser_loss`): p(a | s, F) is then proportional to p_s(a | s) 1[z(a) outside F], the
    base's own proportions over the options left, learnt by one network that sampling calls once per step.

    `guard` is a `FailureSetClassifier` trained beside it on the same rows and failure sets; sampling may
    follow its gradient in the last reverse steps (`failure_guard_steps`) to move what the denoiser let onto a
    failed option. `guard_trained` stays False in a checkpoint saved before the guard existed.
    """

    def __init__(self, config: CCDPConfig):
        super().__init__()
        width = HIDDEN_WIDTH
        self.history_cond_dim = config.history_length * (config.frame_dim + config.action_dim)
        base_cond_dim = config.n_obs_steps * config.frame_dim + self.history_cond_dim + 2
        self.set_embedding = _set_embedding(config, width)
        self.unet = with_small_batch_convolutions(
            DiffusionConditionalUnet1d(config, global_cond_dim=base_cond_dim + width)
        )
        self.guard = FailureSetClassifier(config)
        self.register_buffer("guard_trained", torch.zeros((), dtype=torch.bool))

    def forward(self, noisy: Tensor, timestep: Tensor, state: Tensor, z: Tensor, z_mask: Tensor) -> Tensor:
        """noisy (R, horizon, A); timestep (R,); state (R, state_cond_dim); z (R, N, z_dim) with z_mask
        (R, N), at least one failure per row -> predicted noise (R, horizon, A)."""
        ones = state.new_ones(state.shape[0], 1)
        no_history = state.new_zeros(state.shape[0], self.history_cond_dim)
        failures = self.set_embedding(z).masked_fill(~z_mask[..., None], float("-inf")).amax(dim=1)
        cond = torch.cat([state, ones, no_history, 0 * ones, failures], dim=-1)
        return self.unet(noisy, timestep, global_cond=cond)

    @torch.no_grad()
    def start_from(self, base: BaseDenoiser) -> None:
        """Copy the base UNet's weights; the condition columns the base lacks (F's embedding) start at
        zero."""
        own = self.unet.state_dict()
        for name, value in base.unet.state_dict().items():
            target = own[name]
            if target.shape == value.shape:
                target.copy_(value)
            else:  # a FiLM encoder's input weights: (out, base_cond + width)
                target.zero_()[:, : value.shape[1]].copy_(value)


def _set_embedding(config: CCDPConfig, width: int) -> nn.Module:
    """An MLP of one failure's z (its Fourier features with `z_fourier_octaves`), maxed over F by the
    heads. With octaves the Linear layers sit at other indices than without, so a base checkpoint's untrained
    head of the other kind loads as missing and unexpected keys, never as a size mismatch."""
    dim = config.failure_feature_dim
    if not config.z_fourier_octaves:
        return nn.Sequential(nn.Linear(dim, width), nn.Mish(), nn.Linear(width, width))
    features = FourierFeatures(config.z_fourier_octaves)
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


def _step_embedding(config: CCDPConfig, width: int) -> nn.Module:
    """The diffusion step as a `width` vector, for the FiLM conditions of the classifier."""
    return nn.Sequential(
        DiffusionSinusoidalPosEmb(config.diffusion_step_embed_dim),
        nn.Linear(config.diffusion_step_embed_dim, width),
        nn.Mish(),
    )


def _z_condition(z: Tensor, keep_z: Tensor) -> Tensor:
    """z with its keep flag: a dropped z (keep 0) is zeroed, so the head learns eps_z_null on the same
    data."""
    return torch.cat([z * keep_z, keep_z], dim=-1)


class _FiLMBlock(nn.Module):
    def __init__(self, width: int):
        super().__init__()
        self.norm = nn.LayerNorm(width)
        self.film = nn.Linear(width, 2 * width)
        self.mlp = nn.Sequential(nn.Linear(width, width), nn.Mish(), nn.Linear(width, width))

    def forward(self, h: Tensor, cond: Tensor) -> Tensor:
        scale, shift = self.film(cond).chunk(2, dim=-1)
        return h + self.mlp(self.norm(h) * (1 + scale) + shift)
