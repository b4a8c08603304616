"""CCDPPolicy and CCDPModel: LeRobot's diffusion policy composed at every denoising step with a recovery head.

Split as LeRobot splits DiffusionPolicy and DiffusionModel. `CCDPPolicy` keeps the rollout (`Rollout`:
windows, plans, every row's failures) and the failure signals, and hands each plan to the recovery mode's
sampler (`samplers.py`). `CCDPModel` holds the networks, the base loss and the one reverse diffusion the
samplers call; the recovery head (`heads/`) gives its own loss and its estimate for rows with failures, and
eq. (4) itself lives in `composition.py`.
"""

import logging
from pathlib import Path

import torch
import torch.nn.functional as F  # noqa: N812
from huggingface_hub import ModelCard
from lerobot.policies.diffusion.modeling_diffusion import _make_noise_scheduler
from lerobot.policies.pretrained import PreTrainedPolicy
from safetensors.torch import load_file
from torch import Tensor, nn

from lerobot_ccdp.compat.threads import leave_a_core
from lerobot_ccdp.policy.base_denoiser import P_DROP_HISTORY, P_DROP_STATE, BaseDenoiser, base_estimates
from lerobot_ccdp.policy.checkpoint_files import checked_load, make_model_card, refuse_unloadable_weights
from lerobot_ccdp.policy.composition import POLICY_Z_REFERENCE, CompositionWeights, compose_eps
from lerobot_ccdp.policy.config_checks import edited_since, settings_of
from lerobot_ccdp.policy.configuration_ccdp import FAILURE_FLAG_KEY, CCDPConfig
from lerobot_ccdp.policy.failure_buffer import failed_rows, row_index
from lerobot_ccdp.policy.failure_features import FailureFeature
from lerobot_ccdp.policy.failure_signal import FailureSignalFile, warn_nothing_reports_failures
from lerobot_ccdp.policy.heads import make_head
from lerobot_ccdp.policy.heads.registry import Estimate
from lerobot_ccdp.policy.image_encoder import ImageEncoder
from lerobot_ccdp.policy.observations import (
    ConstantInputs,
    demonstration_windows,
    failure_flags,
    observation_frames,
    refuse_non_finite_batch,
    refuse_non_finite_plan,
    refuse_non_finite_stats,
    refuse_unfit_noise,
    refuse_unknown_cameras,
    refuse_unusable_weights,
    reported_failure_features,
)
from lerobot_ccdp.policy.outcome_index import OutcomeIndex
from lerobot_ccdp.policy.outcome_table import build_outcome_table
from lerobot_ccdp.policy.rollout_memory import Rollout, RolloutMemory
from lerobot_ccdp.policy.samplers import SAMPLERS
from lerobot_ccdp.policy.training_checks import refuse_fresh_training, refuse_resume_with_nothing_to_train

logger = logging.getLogger(__name__)


class CCDPPolicy(PreTrainedPolicy):
    """Composition of Conditional Diffusion Policies (Razmjoo et al., IROS 2025).

    After a failed attempt (flagged by the env as `observation.failure`, or reported with
    `report_failure`), the row's failure feature z joins its failure buffer and every later sample of that
    row is drawn from eq. (4), which pushes samples away from what already failed. `recovery_mode` picks
    CCDP, plain DP (ignore failures) or DP* (reject candidates near a failure), all on the same weights."""

    config_class = CCDPConfig
    name = "ccdp"

    def __init__(self, config: CCDPConfig, dataset_meta=None, dataset_stats=None, **kwargs):
        super().__init__(config)
        config.validate_features()
        leave_a_core(str(config.device))
        if dataset_meta is not None:  # a fresh policy for a dataset: lerobot-train without --policy.path
            refuse_fresh_training(config, dataset_meta)
        self.config = config
        self.model = CCDPModel(config, dataset_meta, dataset_stats)
        self.failure_signal = (
            FailureSignalFile(config.failure_signal_file) if config.failure_signal_file else None
        )
        # Whether anything could tell this policy about a failure (warned about once otherwise).
        self._heard_failure_source = self.failure_signal is not None
        self._warned_deaf = False
        # rollouts begun since the policy was made: with row_noise_streams, part of each row's seed
        self._rollouts = 0
        self._settings = settings_of(config)  # to check and apply an edit of policy.config after this
        self.reset()

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path: str | Path, **kwargs) -> "CCDPPolicy":
        """LeRobot's load, checked (`checkpoint_files.checked_load`): no dataset is read, and a wrong path, a
        damaged file or weights that do not fit are named with the fix."""
        load = super().from_pretrained
        return checked_load(
            lambda config, **rest: load(pretrained_name_or_path, config=config, **rest),
            pretrained_name_or_path,
            **kwargs,
        )

    @classmethod
    def _load_as_safetensor(cls, model: "CCDPPolicy", model_file: str, map_location: str, strict: bool):
        """LeRobot's load, after `refuse_unloadable_weights` (shapes and dtypes named, not truncated). The
        untrained recovery head of a base checkpoint that starts another head's recovery stage
        (`--policy.recovery_head`) is left out where its shapes differ, as torch would refuse it."""
        other_head = refuse_unloadable_weights(model.state_dict(), model_file)
        if not other_head:
            return super()._load_as_safetensor(model, model_file, map_location, strict)
        saved = load_file(model_file, device=str(map_location))
        model.load_state_dict({k: v for k, v in saved.items() if k not in other_head}, strict=False)
        return model

    def generate_model_card(
        self, dataset_repo_id: str, model_type: str, license: str | None, tags: list[str] | None
    ) -> ModelCard:
        """The card push_model_to_hub writes (lerobot-train --policy.push_to_hub): LeRobot's has no ccdp."""
        return make_model_card(self.config, dataset_repo_id, license, tags, bool(self.model.recovery_trained))

    # ----- training -------------------------------------------------------------------------------------

    def get_optim_params(self) -> list:
        """lerobot-train's parameters to optimise (the base's are frozen in the recovery stage). Asked once
        per run, before the first step: a resume that has nothing left to train is refused here."""
        refuse_resume_with_nothing_to_train(self.config.pretrained_path)
        return [p for p in self.parameters() if p.requires_grad]

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """The model's loss for the stage the config names. A non-finite loss stops training (LeRobot would
        train on to a NaN checkpoint and exit 0)."""
        loss, info = self.model.compute_loss(batch)
        if not bool(torch.isfinite(loss)):
            refuse_non_finite_batch(
                batch,
                f"The {self.config.training_stage} loss is {loss.item()} although the "
                "batch is finite: lower --policy.optimizer_lr, or resume from an earlier checkpoint.",
            )
        return loss, info

    # ----- acting ---------------------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget everything about the rollout: windows, plans and every row's failures."""
        if getattr(self, "_rollout", None) is not None:
            self._warn_if_deaf()
        self._rollout: Rollout | None = None
        self._warned_untrained = False
        self._planned_with_recovery = False  # whether this episode planned in a mode that uses failures

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> Tensor:
        """One action per row. Rows whose env flags `observation.failure` remember the failure and re-plan;
        the other rows keep executing their current chunk."""
        memory = self._observe(batch, noise)
        rows = memory.needs_plan()
        if rows.any():
            memory.set_plan(rows, self._sample(rows, noise), start=self.config.n_obs_steps - 1)
        return memory.pop_action()

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> Tensor:
        """A fresh chunk (B, n_action_steps, A) for every row from its current windows and failures; it
        becomes the rows' plan, as the chunk a client executes next."""
        memory = self._observe(batch, noise)
        rows = torch.ones(memory.batch_size, dtype=torch.bool, device=memory.frames.device)
        memory.set_plan(rows, self._sample(rows, noise), start=self.config.n_obs_steps - 1)
        return memory.plan.clone()

    def report_failure(self, rows: int | list[int] | Tensor | None = None, z: Tensor | None = None) -> None:
        """Record a failed attempt from a custom control loop (e.g. a real robot's failure detector).

        `rows` are the batch rows that failed (all rows if None). z defaults to the failure feature of the
        latest observation and the attempt's chunks; pass `z` (len(rows), z_dim), normalised, to override it.
        Those rows re-plan from their next observation, which should be the attempt's restored start pose.
        A report before any select_action() since reset() is refused: no attempt was made in this episode,
        and the policy does not yet know its rows.
        """
        self._heard_failure_source = True
        index = row_index(rows)
        if self._rollout is None:
            raise RuntimeError(
                "report_failure() came before any select_action() since the policy was made or reset(): "
                "this episode has made no attempt yet, so there is no failure to remember (reset() began a "
                "new episode and forgot the last one's). Call it after the select_action() calls of the "
                "attempt that failed."
            )
        memory = self._rollout.memory
        mask = failed_rows(index, rows, memory.batch_size, memory.frames.device)
        if not mask.any():
            return  # an empty list of rows: nothing failed
        if z is not None:
            cfg = self.config
            z = reported_failure_features(
                z, int(mask.sum()), cfg.failure_feature_dim, cfg.failure_feature, mask.device
            )
        self._rollout.record_failures(mask, self.model.feature, self.model.outcomes, z)

    def _warn_if_deaf(self) -> None:
        """An episode ended with recovery on and nothing that could report a failure: say so, once."""
        if self._heard_failure_source or self._warned_deaf or not self._planned_with_recovery:
            return
        self._warned_deaf = True
        warn_nothing_reports_failures(self.config.recovery_mode)

    def failure_count(self) -> Tensor:
        """How many failures each row currently remembers."""
        rollout = self._rollout
        return torch.zeros(0, dtype=torch.long) if rollout is None else rollout.failures.count.clone()

    def _observe(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> RolloutMemory:
        """Take in one observation per row: remember flagged failures, then push the frame. Every input (the
        frame, the failure flags, the caller's noise) is checked before anything is remembered."""
        refuse_unusable_weights(self.model.constant_inputs.value)  # moves and casts with the weights
        if edited_since(self.config, self._settings):  # e.g. policy.config.w_z = 3 after loading
            self.model.set_weights()
            self._settings = settings_of(self.config)
        frame = self.model.frames(batch)
        if frame.ndim == 3:  # (B, T, D) from a dataset: act on the latest frame
            frame = frame[:, -1]
        flag = batch.get(FAILURE_FLAG_KEY)
        failed = None if flag is None else failure_flags(flag, frame.shape[0]).to(frame.device)
        refuse_unfit_noise(noise, (frame.shape[0], self.config.horizon, self.config.action_dim))
        rollout = self._rollout
        fresh = rollout is None or rollout.memory.batch_size != frame.shape[0]
        if fresh:
            rollout = self._rollout = Rollout.after(
                rollout, self.config, frame.shape[0], frame.device, self._rollouts
            )
            self._rollouts += 1
        if failed is not None:
            self._heard_failure_source = True
            if failed.any():
                rollout.record_failures(failed, self.model.feature, self.model.outcomes)
        if self.failure_signal is not None and self.failure_signal.poll():
            if fresh:
                logger.warning(
                    "%s appeared before any action since reset(): no attempt to remember, ignored.",
                    self.failure_signal.path,
                )
            else:
                every_row = torch.ones(frame.shape[0], dtype=torch.bool, device=frame.device)
                rollout.record_failures(every_row, self.model.feature, self.model.outcomes)
        rollout.memory.push_frame(frame)
        return rollout.memory

    def _sample(self, rows: Tensor, noise: Tensor | None) -> Tensor:
        """Chunks (R, horizon, A) for the selected rows, from the configured recovery mode's sampler."""
        mode, plan = self.config.recovery_mode, self._rollout.plan_rows(rows, noise)
        self._planned_with_recovery |= mode != "dp"
        if mode == "ccdp" and plan.z_mask.any() and not bool(self.model.recovery_trained):
            if not self._warned_untrained:
                logger.warning(
                    "recovery_mode=ccdp but the recovery head is untrained (base-stage checkpoint): "
                    "sampling as plain DP. Train the recovery stage to use failures."
                )
                self._warned_untrained = True
            mode = "dp"
        chunks = SAMPLERS[mode](self.model, plan)
        if not bool(torch.isfinite(chunks).all()):
            refuse_non_finite_plan(self.state_dict(), self.model.weights, rows, chunks, plan, mode)
        return chunks


class CCDPModel(nn.Module):
    """The base denoiser (eps_a, eps_s, eps_h in one network), the recovery head, the camera encoder, the
    outcome table and the noise schedule. `compute_loss` trains the stage the config names; `denoise` runs the
    reverse diffusion with eq. (4) (or the head's own composition) at every step."""

    def __init__(self, config: CCDPConfig, dataset_meta=None, dataset_stats=None):
        super().__init__()
        self.config = config
        self.base = BaseDenoiser(config)
        self.images = ImageEncoder(config) if config.image_features else None
        self.head = make_head(config)
        self.recovery = self.head.network(config)
        self.outcomes = OutcomeIndex()
        self.constant_inputs = ConstantInputs(config)
        # Whether the recovery head has been trained; a base-only checkpoint composes nothing for failures.
        self.register_buffer("recovery_trained", torch.zeros((), dtype=torch.bool))
        self.noise_scheduler = _make_noise_scheduler(
            config.noise_scheduler_type,
            num_train_timesteps=config.num_train_timesteps,
            beta_start=config.beta_start,
            beta_end=config.beta_end,
            beta_schedule=config.beta_schedule,
            clip_sample=config.clip_sample,
            clip_sample_range=config.clip_sample_range,
            prediction_type=config.prediction_type,
        )
        self.feature = FailureFeature(config)
        self.set_weights()
        base_stage = config.training_stage == "base"
        if dataset_stats is not None and base_stage:
            refuse_non_finite_stats(config, dataset_stats)
            self.constant_inputs.fill(config, dataset_stats)
        if dataset_meta is not None and base_stage and config.failure_feature != "action":
            self.outcomes.fill(*build_outcome_table(config, dataset_meta, dataset_stats))
        self._set_trainable()

    # ----- training -------------------------------------------------------------------------------------

    def set_weights(self) -> None:
        """The weights of eq. (4), from the config (again after it was edited)."""
        c = self.config
        self.weights = CompositionWeights(
            w_h=c.w_h, w_z=c.w_z, z_reference=POLICY_Z_REFERENCE, w_z_steps=c.w_z_steps
        )

    def _set_trainable(self) -> None:
        """The recovery stage trains eps_z only: the base network and the camera encoder are frozen."""
        base_stage = self.config.training_stage == "base"
        self.base.requires_grad_(base_stage)
        if self.images is not None:
            self.images.requires_grad_(base_stage)
        self.recovery.requires_grad_(not base_stage)

    def compute_loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Loss of the stage the config names: the base denoiser on demos, or the recovery head's on its
        data (`heads/`)."""
        if self.config.training_stage == "base":
            return self._base_loss(batch)
        return self.head.loss(self, batch)

    def _base_loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        cfg = self.config
        state, history, chunk, pad = self.windows(batch)
        b = chunk.shape[0]
        keep_s = (torch.rand(b, 1, device=chunk.device) >= P_DROP_STATE).float()
        keep_h = (torch.rand(b, 1, device=chunk.device) >= P_DROP_HISTORY).float() * float(
            cfg.history_length > 0
        )
        noise, timesteps, noisy = self.noised(chunk)
        loss = F.mse_loss(
            self.base(noisy, timesteps, state, keep_s, history, keep_h), noise, reduction="none"
        )
        if cfg.do_mask_loss_for_padding and pad is not None:
            loss = loss * ~pad[:, cfg.history_length :, None]
        return loss.mean(), {}

    def windows(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        """A demonstration batch as the base sees it (`observations.demonstration_windows`)."""
        refuse_unknown_cameras(self.config, batch)
        return demonstration_windows(self.config, self.frames(batch), batch)

    def noised(self, chunk: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(noise, timesteps, noisy chunk): `chunk` noised at a random training timestep per row."""
        noise = torch.randn_like(chunk)
        timesteps = torch.randint(
            0, self.noise_scheduler.config.num_train_timesteps, (chunk.shape[0],), device=chunk.device
        )
        return noise, timesteps, self.noise_scheduler.add_noise(chunk, noise, timesteps)

    # ----- the reverse diffusion ------------------------------------------------------------------------

    @torch.no_grad()
    def sample_exploratory(self, state: Tensor, w_s: float, noise: Tensor | None = None) -> Tensor:
        """Chunks (R, horizon, A) drawn from eq. (7) for normalised state conditions
        (R, n_obs_steps * frame_dim): no history, no failures. Recovery synthesis uses it to propose candidate
        actions around demo states."""
        cfg = self.config
        r = state.shape[0]
        if noise is None:
            noise = torch.randn(r, cfg.horizon, cfg.action_dim, device=state.device)
        history = torch.zeros(r, self.base.history_cond_dim, device=state.device)
        no_failures = torch.zeros(r, 0, cfg.failure_feature_dim, device=state.device)
        weights = CompositionWeights.exploration(w_s)
        return self.denoise(noise, state, history, no_failures, no_failures[..., 0].bool(), weights)

    def denoise(
        self,
        sample: Tensor,
        state: Tensor,
        history: Tensor,
        z: Tensor,
        z_mask: Tensor,
        weights: CompositionWeights | None = None,
        generators: list[torch.Generator] | None = None,
    ) -> Tensor:
        """Reverse diffusion with eq. (4) at every step (with the policy's weights unless `weights` is given):
        one base call and at most one recovery call per step, whatever the number of failures. Where rows hold
        failure slots, the head's estimate says how the failures enter (`heads/`). The reverse steps' noise
        comes from `generators` (one per row, `samplers.row_generators`) when given, else from torch's global
        generator."""
        weights = weights or self.weights
        self.noise_scheduler.set_timesteps(self.config.num_inference_steps or self.config.num_train_timesteps)
        timesteps = [int(t) for t in self.noise_scheduler.timesteps]
        if z.shape[1]:
            estimate = self.head.estimate(self, weights, state, history, z, z_mask, timesteps)
        else:
            estimate = self.estimate_without_failures(weights, state, history)
        for t in timesteps:
            eps = estimate(sample, t)
            sample = self.noise_scheduler.step(eps, t, sample, generator=generators).prev_sample
        return sample

    def estimate_without_failures(
        self, weights: CompositionWeights, state: Tensor, history: Tensor
    ) -> Estimate:
        """eq. (4) without failure terms (the base network's terms only), for rows that remember none."""
        base = base_estimates(
            self.base, weights.base_terms(state.new_zeros(state.shape[0], dtype=torch.long)), state, history
        )

        def estimate(sample: Tensor, t: int) -> Tensor:
            by_term = base(sample, t)
            return compose_eps(weights, by_term.get("a"), by_term.get("s"), by_term.get("h"))

        return estimate

    # ----- inputs ---------------------------------------------------------------------------------------

    def frames(self, batch: dict[str, Tensor]) -> Tensor:
        """Observation frames (B, [T,] frame_dim) as the networks see them
        (`observations.observation_frames`)."""
        return observation_frames(self.config, self.images, batch, self.constant_inputs)
