"""The `set_denoiser` head: eps_{s,F}, one term for the whole failure set in eq. (4)
(`composition.compose_with_failure_set`), trained on the base's own samples at option starts and along the
demonstrations (lerobot-ccdp-synthesize), with a failure-set classifier beside it as its guard."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import torch
import torch.nn.functional as F  # noqa: N812
from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d
from lerobot.utils.constants import ACTION
from torch import Tensor, nn

from lerobot_ccdp.policy.base_denoiser import BaseDenoiser, base_estimates
from lerobot_ccdp.policy.composition import (
    CompositionWeights,
    compose_with_failure_set,
    guide_away_from_failures,
)
from lerobot_ccdp.policy.configuration_ccdp import SIBLING_COUNT_KEY, SIBLING_FEATURES_KEY, CCDPConfig
from lerobot_ccdp.policy.failure_buffer import draw_failure_sets, draw_state_failure_sets, stratum_weights
from lerobot_ccdp.policy.heads.classifier import (
    FAILURE_SET_TRAIN_SIZE,
    HIDDEN_WIDTH,
    FailureSetClassifier,
    classifier_loss,
    no_repeat_gradient,
    set_embedding,
)
from lerobot_ccdp.policy.heads.registry import Estimate, RecoveryHead, register_head
from lerobot_ccdp.policy.small_batch_convolutions import with_small_batch_convolutions

if TYPE_CHECKING:  # the model module imports the heads
    from lerobot_ccdp.policy.modeling_ccdp import CCDPModel


class FailureSetDenoiser(nn.Module):
    """eps_{s,F}(a_t, k): the noise estimate of p_s restricted to the chunks whose outcome lies outside the
    failure set F.

    A copy of the base UNet whose global condition is the base's own with the state kept and the history
    dropped, followed by an embedding of F (a max over an MLP of each z_i, so neither F's order nor a repeated
    failure changes it). `start_from` copies the base with the set's condition weights zeroed, so training
    starts from eps_s exactly. Trained on chunks the base samples at option starts and along the demos, with F
    drawn independently of each row and the rows whose own outcome lies in F left out
    (`SetDenoiserHead.loss`): p(a | s, F) is then proportional to p_s(a | s) 1[z(a) outside F], the base's own
    proportions over the options left, learnt by one network that sampling calls once per step.

    `guard` is a `FailureSetClassifier` trained beside it on the same rows and failure sets; sampling may
    follow its gradient in the last reverse steps (`failure_guard_steps`) to move what the denoiser let onto a
    failed option. `guard_trained` stays False in a checkpoint saved before the guard existed.
    """

    def __init__(self, config: CCDPConfig):
        super().__init__()
        width = HIDDEN_WIDTH
        self.history_cond_dim = config.history_length * (config.frame_dim + config.action_dim)
        base_cond_dim = config.n_obs_steps * config.frame_dim + self.history_cond_dim + 2
        self.set_embedding = set_embedding(config, width)
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


@register_head("set_denoiser")
class SetDenoiserHead(RecoveryHead):
    network = FailureSetDenoiser
    training_data = "base_samples"
    own_settings = (
        "w_z_steps",
        "failure_guard_steps",
        "stratum_weights",
        "state_failure_sets",
    )

    @classmethod
    def describe(cls, settings: Mapping[str, Any]) -> str:
        w_h, w_z = settings["w_h"], settings["w_z"]
        form = f"w_h {w_h:g}; failures by the failure-set denoiser eps_(s,F), w_z {w_z:g}"
        return form + w_z_window(
            settings.get("w_z_steps"),
            settings.get("failure_guard_steps", 0),
            settings.get("failure_guard_weight", 1.0),
        )

    @classmethod
    def unet_condition(cls, step: int, base_condition: int, z_size: int) -> int | None:
        return base_condition

    @classmethod
    def check_config(cls, config: CCDPConfig) -> None:
        if config.n_obs_steps != 1:
            raise ValueError(
                f"recovery_head='set_denoiser' trains on one-frame rows of a synthesised dataset: it needs "
                f"n_obs_steps=1; got {config.n_obs_steps}. Use --policy.recovery_head=unet."
            )
        if config.image_features:
            raise ValueError(
                "recovery_head='set_denoiser' conditions on the state of synthesised rows, which carry no "
                "camera images yet: use --policy.recovery_head=unet with cameras."
            )

    def loss(self, model: CCDPModel, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """eps_{s,F} on the rows of a set-denoiser dataset: chunks the base samples at option starts and along
        the demonstrations, with their state (lerobot-ccdp-synthesize, `synthesize.set_denoiser_frames`). Each
        row gets a failure set F of 1..FAILURE_SET_TRAIN_SIZE z drawn from other rows (so F is independent of
        the row's own chunk); rows whose own z lies within delta_z of a failure in F are left out. The rows
        kept are p_s(a | s) q(F) 1[z(a) outside F], whose conditional given (s, F) is p_s restricted to the
        options outside F in the base's proportions: DP*'s rejection, distilled. The first step copies the
        base into the head (`FailureSetDenoiser.start_from`). The head's guard learns P(repeat | a_t, s, F) on
        the same noisy rows and failure sets, every row included, as the classifier head does."""
        cfg = model.config
        state, chunk = model.frames(batch), batch[ACTION]
        if state.ndim != 2 or chunk.ndim != 3 or chunk.shape[1] != cfg.horizon:
            raise ValueError(
                "The set denoiser trains on synthesised rows: one state (B, D) and one whole chunk (B, "
                f"{cfg.horizon}, A) per row; got {tuple(state.shape)} and {tuple(chunk.shape)}. Make the "
                "dataset with lerobot-ccdp-synthesize from this checkpoint."
            )
        if chunk.shape[0] < 2:
            raise ValueError(
                "The set denoiser draws each row's failures from the other rows: use --batch_size >= 2."
            )
        if not bool(model.recovery_trained):
            model.recovery.start_from(model.base)
            model.recovery_trained.fill_(True)
        z = model.feature.from_chunk(chunk, model.outcomes)
        if cfg.state_failure_sets:
            siblings, count = _siblings(batch, f"--policy.state_failure_sets={cfg.state_failure_sets}")
            z_set, z_mask, repeats = draw_state_failure_sets(
                z, siblings, count, FAILURE_SET_TRAIN_SIZE, cfg.delta_z, cfg.state_failure_sets
            )
        else:
            z_set, z_mask, repeats = draw_failure_sets(z, FAILURE_SET_TRAIN_SIZE, cfg.delta_z)
        noise, timesteps, noisy = model.noised(chunk)
        loss = F.mse_loss(model.recovery(noisy, timesteps, state, z_set, z_mask), noise, reduction="none")
        kept = (~repeats).to(loss.dtype)
        if cfg.stratum_weights:
            siblings, count = _siblings(batch, "--policy.stratum_weights=true")
            weight = kept * stratum_weights(z_set, z_mask, siblings, count, cfg.delta_z)
        else:
            weight = kept
        loss = (loss.mean(dim=(1, 2)) * weight).sum() / weight.sum().clamp_min(1.0)
        guard_loss = classifier_loss(model.recovery.guard, noisy, timesteps, state, z_set, z_mask, repeats)
        model.recovery.guard_trained.fill_(True)
        return loss + guard_loss, {"kept_rows": float(kept.mean()), "guard_loss": guard_loss.item()}

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
        """`compose_with_failure_set` for the rows with failures (eps_{s,F} in one recovery call, plus the
        base terms whose coefficient is not zero at that step's weights: none at w_s = w_z = 1, w_h = 0),
        guided by the head's guard in the last `failure_guard_steps` steps (`guide_away_from_failures` at
        `failure_guard_weight`), and eq. (4) without failure terms for the other rows."""
        cfg = model.config
        guarded = set(timesteps[max(len(timesteps) - cfg.failure_guard_steps, 0) :])
        if guarded and not bool(model.recovery.guard_trained):
            raise ValueError(
                f"--policy.failure_guard_steps={cfg.failure_guard_steps} follows the set denoiser's "
                "guard, which this checkpoint never trained (saved before the guard existed): set "
                "--policy.failure_guard_steps=0, or train the recovery stage again."
            )
        failed = z_mask.any(dim=1)
        plain_rest = model.estimate_without_failures(weights, state[~failed], history[~failed])
        step_weights = {t: weights.at_step(index) for index, t in enumerate(timesteps)}
        base = {
            w: base_estimates(model.base, w.failure_set_base_terms(), state[failed], history[failed])
            for w in set(step_weights.values())
        }
        z_failed, mask_failed, state_failed = z[failed], z_mask[failed], state[failed]

        def estimate(sample: Tensor, t: int) -> Tensor:
            eps = torch.empty_like(sample)
            if not failed.all():
                eps[~failed] = plain_rest(sample[~failed], t)
            noisy = sample[failed]
            step = torch.full((noisy.shape[0],), t, dtype=torch.long, device=sample.device)
            estimates = base[step_weights[t]](noisy, t) | {
                "sF": model.recovery(noisy, step, state_failed, z_failed, mask_failed)
            }
            eps[failed] = compose_with_failure_set(step_weights[t], estimates)
            if t in guarded:
                gradient = no_repeat_gradient(
                    model.recovery.guard, noisy, step, state_failed, z_failed, mask_failed, cfg.delta_z
                )
                alpha_bar = model.noise_scheduler.alphas_cumprod[t].to(sample.device)
                eps[failed] = guide_away_from_failures(
                    eps[failed], gradient, alpha_bar, cfg.failure_guard_weight
                )
            return eps

        return estimate


def _siblings(batch: dict[str, Tensor], option: str) -> tuple[Tensor, Tensor]:
    """The outcomes of the chunks the synthesis sampled at each row's state (B, K, z_dim) and how many of
    them are real (B,)."""
    siblings, count = batch.get(SIBLING_FEATURES_KEY), batch.get(SIBLING_COUNT_KEY)
    if siblings is None or count is None or siblings.ndim != 3:
        raise ValueError(
            f"{option} reads each row's sibling outcomes ({SIBLING_FEATURES_KEY!r}, "
            f"{SIBLING_COUNT_KEY!r}), which this dataset lacks: make it anew with "
            "lerobot-ccdp-synthesize from this checkpoint, or leave the option out."
        )
    return siblings, count.reshape(-1)


def w_z_window(count: int | None, guard: int = 0, guard_weight: float = 1.0) -> str:
    """The set denoiser's reverse steps at w_z (`w_z_steps`) and those its guard guides
    (`failure_guard_steps`, at `failure_guard_weight`), as the forms table says them."""
    weight = f" at weight {guard_weight:g}" if guard_weight != 1 else ""
    guarded = f"; its guard on the last {guard} steps{weight}" if guard else ""
    return ("" if count is None else f" on the first {count} steps, 1 after") + guarded
