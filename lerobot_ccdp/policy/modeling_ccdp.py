"""CCDPPolicy and CCDPModel: LeRobot's diffusion policy composed at every denoising step with failure-recovery
heads.

Split as LeRobot splits DiffusionPolicy and DiffusionModel. `CCDPPolicy` keeps what a rollout needs
(observation windows, plans, every row's failures, the failure signals) and hands each plan to the recovery
mode's sampler (`samplers.py`). `CCDPModel` holds the networks, the losses of both stages and the one reverse
diffusion the samplers call; eq. (4) itself, and which of its terms run, live in `policy/composition.py`.
"""

import logging
from pathlib import Path

import torch
import torch.nn.functional as F  # noqa: N812
from huggingface_hub import ModelCard
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.diffusion.modeling_diffusion import _make_noise_scheduler
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION
from torch import Tensor, nn

from lerobot_ccdp.policy.checkpoint_files import (
    HUB_DOWNLOAD_KEYS,
    checkpoint_loading,
    ignore_saved_signal_file,
    refuse_other_checkpoint,
    refuse_unfit_outcome_table,
    refuse_unfit_weights,
    refuse_unloadable_weights,
    saved_config,
)
from lerobot_ccdp.policy.composition import (
    CompositionWeights,
    compose_eps,
    compose_with_failure_set,
    guide_away_from_failures,
    log_no_repeat,
    recovery_conditions,
)
from lerobot_ccdp.policy.config_checks import edited_since, settings_of
from lerobot_ccdp.policy.configuration_ccdp import (
    FAILURE_FEATURE_KEY,
    FAILURE_FLAG_KEY,
    SIBLING_COUNT_KEY,
    SIBLING_FEATURES_KEY,
    CCDPConfig,
)
from lerobot_ccdp.policy.denoisers import BaseDenoiser, make_recovery_denoiser
from lerobot_ccdp.policy.failure_buffer import (
    FailureBuffer,
    distinct_failures,
    draw_failure_sets,
    draw_state_failure_sets,
    stratum_weights,
)
from lerobot_ccdp.policy.failure_features import FailureFeature
from lerobot_ccdp.policy.failure_signal import FailureSignalFile
from lerobot_ccdp.policy.image_encoder import ImageEncoder
from lerobot_ccdp.policy.model_card import make_model_card
from lerobot_ccdp.policy.noise_streams import row_generators
from lerobot_ccdp.policy.observations import (
    ConstantInputs,
    failure_flags,
    observation_frames,
    refuse_non_finite_batch,
    refuse_non_finite_stats,
    refuse_unfit_noise,
    refuse_unknown_cameras,
    refuse_unusable_weights,
    reported_failure_features,
)
from lerobot_ccdp.policy.outcome_index import OutcomeIndex
from lerobot_ccdp.policy.outcome_table import build_outcome_table
from lerobot_ccdp.policy.rollout_memory import RolloutMemory
from lerobot_ccdp.policy.samplers import SAMPLERS, PlanRows
from lerobot_ccdp.policy.training_checks import refuse_fresh_training, refuse_resume_with_nothing_to_train

logger = logging.getLogger(__name__)

# Condition dropout while training (independent per condition): dropping the state and the history trains
# eps_a, dropping one trains eps_s or eps_h; dropping z trains the recovery head's eps_z_null.
P_DROP_STATE = 0.3
P_DROP_HISTORY = 0.5
P_DROP_FAILURE = 0.1
# Most failures remembered per batch row (the oldest is forgotten beyond it), and drawn for one training row
# of the classifier and the set denoiser.
MAX_FAILURES = 8
FAILURE_SET_TRAIN_SIZE = 3


class CCDPPolicy(PreTrainedPolicy):
    """Composition of Conditional Diffusion Policies (Razmjoo et al., IROS 2025).

    After a failed attempt (flagged by the env as `observation.failure`, or reported with
    `report_failure`), the row's failure feature z joins its failure buffer and every later sample of that
    row is drawn from eq. (4), which pushes samples away from what already failed. `recovery_mode` picks
    CCDP, plain DP (ignore failures) or DP* (reject candidates near a failure), all on the same weights.
    """

    config_class = CCDPConfig
    name = "ccdp"

    def __init__(self, config: CCDPConfig, dataset_meta=None, dataset_stats=None, **kwargs):
        super().__init__(config)
        config.validate_features()
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
        self._streams: list[torch.Generator] | None = None
        self._settings = settings_of(config)  # to check and apply an edit of policy.config after this
        self.reset()

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path: str | Path, **kwargs) -> "CCDPPolicy":
        """A checkpoint carries its own outcome table. LeRobot's make_policy hands from_pretrained the
        dataset's metadata and stats too, and from_pretrained passes them on to __init__ (under
        lerobot-record: a new, empty recording dataset without the label column); they are dropped so that
        loading never reads a dataset. A local folder is checked first (`checkpoint_loading`): a wrong path or
        a damaged file is named with the fix; so is a checkpoint of another policy type or action size, or
        whose weights do not fit (`refuse_unfit_weights`). A `failure_signal_file` only the checkpoint names
        is dropped: a checkpoint never chooses a file to watch."""
        for key in ("dataset_meta", "dataset_stats"):
            kwargs.pop(key, None)
        with checkpoint_loading(pretrained_name_or_path):
            hub = {key: kwargs[key] for key in HUB_DOWNLOAD_KEYS if key in kwargs}
            config = kwargs.pop("config", None) or PreTrainedConfig.from_pretrained(
                pretrained_name_or_path, **hub
            )
            saved = saved_config(pretrained_name_or_path, **hub)
            refuse_other_checkpoint(config, saved, pretrained_name_or_path)
            ignore_saved_signal_file(config, saved)
            policy = super().from_pretrained(pretrained_name_or_path, config=config, **kwargs)
            refuse_unfit_weights(
                policy.state_dict(), bool(policy.model.recovery_trained), pretrained_name_or_path, **hub
            )
            refuse_unfit_outcome_table(policy.state_dict(), policy.config, pretrained_name_or_path)
            return policy

    @classmethod
    def _load_as_safetensor(cls, model: "CCDPPolicy", model_file: str, map_location: str, strict: bool):
        """LeRobot's load, after `refuse_unloadable_weights` (shapes and dtypes named, not truncated)."""
        refuse_unloadable_weights(model.state_dict(), model_file)
        return super()._load_as_safetensor(model, model_file, map_location, strict)

    def generate_model_card(
        self, dataset_repo_id: str, model_type: str, license: str | None, tags: list[str] | None
    ) -> ModelCard:
        """Called by push_model_to_hub (lerobot-train --policy.push_to_hub): LeRobot's template has no ccdp
        text."""
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
        if getattr(self, "_memory", None) is not None:
            self._warn_if_deaf()
        self._memory: RolloutMemory | None = None
        self._failures: FailureBuffer | None = None
        self._warned_untrained = False
        self._planned_with_recovery = False  # whether this episode planned in a mode that uses failures

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> Tensor:
        """One action per row. Rows whose env flags `observation.failure` remember the failure and re-plan;
        the other rows keep executing their current chunk."""
        rows = self._observe(batch, noise).needs_plan()
        if rows.any():
            self._memory.set_plan(rows, self._sample(rows, noise), start=self.config.n_obs_steps - 1)
        return self._memory.pop_action()

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
        index = _row_index(rows)
        if self._memory is None:
            raise RuntimeError(
                "report_failure() came before any select_action() since the policy was made or reset(): "
                "this episode has made no attempt yet, so there is no failure to remember (reset() began a "
                "new episode and forgot the last one's). Call it after the select_action() calls of the "
                "attempt that failed."
            )
        mask = self._failed_rows(index, rows)
        if not mask.any():
            return  # an empty list of rows: nothing failed
        if z is not None:
            cfg = self.config
            z = reported_failure_features(
                z, int(mask.sum()), cfg.failure_feature_dim, cfg.failure_feature, mask.device
            )
        self._record_failures(mask, z)

    def _warn_if_deaf(self) -> None:
        """An episode ended with recovery on and nothing that could report a failure: say so, once."""
        if self._heard_failure_source or self._warned_deaf or not self._planned_with_recovery:
            return
        self._warned_deaf = True
        logger.warning(
            "ccdp ran an episode with recovery_mode=%s but nothing could tell it about a failure: no %s in "
            "its inputs, no report_failure() call, no failure_signal_file. It acted as plain diffusion "
            "policy. In lerobot-record, pass --policy.failure_signal_file=/tmp/ccdp_failed and create that "
            "file when an attempt fails (docs/robot.md).",
            self.config.recovery_mode,
            FAILURE_FLAG_KEY,
        )

    def _failed_rows(self, index: Tensor | None, rows: object) -> Tensor:
        """Bool mask (B,) of the failed rows (`index` from `_row_index(rows)`), refusing rows outside the
        batch the policy is acting on."""
        b = self._memory.batch_size
        mask = torch.zeros(b, dtype=torch.bool, device=self._memory.frames.device)
        if index is None:
            return ~mask
        index = index.to(mask.device)
        if index.dtype == torch.bool:
            fits = index.shape == (b,)
        else:  # -1 would name the last row: almost surely a bug in the loop
            fits = not bool(((index < 0) | (index >= b)).any())
        if not fits:
            raise ValueError(
                f"report_failure(rows={rows!r}): the policy acts on {b} row(s), indices 0..{b - 1} (or a "
                "bool mask of that length). Pass the failed rows' indices, or None for every row."
            )
        mask[index] = True
        return mask

    def failure_count(self) -> Tensor:
        """How many failures each row currently remembers."""
        return torch.zeros(0, dtype=torch.long) if self._failures is None else self._failures.count.clone()

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
        fresh = self._memory is None or self._memory.batch_size != frame.shape[0]
        if fresh:
            if self._failures is not None and bool((self._failures.count > 0).any()):
                logger.warning(
                    "The batch went from %d to %d rows without reset(): the %d remembered failure(s) "
                    "are dropped, as rows cannot be matched. Call policy.reset() between rollouts.",
                    self._memory.batch_size,
                    frame.shape[0],
                    int(self._failures.count.sum()),
                )
            cfg = self.config
            self._memory = RolloutMemory(cfg, frame.shape[0], frame.device)
            self._failures = FailureBuffer(
                frame.shape[0], cfg.failure_feature_dim, MAX_FAILURES, frame.device
            )
            self._streams = row_generators(self._rollouts, frame.shape[0]) if cfg.row_noise_streams else None
            self._rollouts += 1
        if failed is not None:
            self._heard_failure_source = True
            if failed.any():
                self._record_failures(failed)
        if self.failure_signal is not None and self.failure_signal.poll():
            if fresh:
                logger.warning(
                    "%s appeared before any action since reset(): no attempt to remember, ignored.",
                    self.failure_signal.path,
                )
            else:
                self._record_failures(torch.ones(frame.shape[0], dtype=torch.bool, device=frame.device))
        self._memory.push_frame(frame)
        return self._memory

    def _record_failures(self, failed: Tensor, z: Tensor | None = None) -> None:
        """Remember z_f for the failed rows and restart them at their next observation."""
        memory, rows = self._memory, failed
        if z is None:
            unplanned = failed & ~memory.attempt_planned
            if not self.model.feature.reads_failure_frame and unplanned.any():
                logger.warning(
                    "Row(s) %s failed before planning any chunk: no chunk to remember.",
                    unplanned.nonzero().flatten().tolist(),
                )
                rows = failed & memory.attempt_planned
            z = self.model.feature.of_failure(
                memory.last_frame, memory.attempt_chunk, memory.latest_chunk, self.model.outcomes
            )
        else:
            z_full = torch.zeros(memory.batch_size, self.config.failure_feature_dim, device=z.device)
            z_full[rows] = z.reshape(-1, self.config.failure_feature_dim).to(z_full.dtype)
            z = z_full
        self._failures.add(rows, z)
        memory.restart(failed)

    def _sample(self, rows: Tensor, noise: Tensor | None) -> Tensor:
        """Chunks (R, horizon, A) for the selected rows, from the configured recovery mode's sampler."""
        memory, mode = self._memory, self.config.recovery_mode
        z, z_mask = self._failures.padded(rows)
        self._planned_with_recovery |= mode != "dp"
        if mode == "ccdp" and z_mask.any() and not bool(self.model.recovery_trained):
            if not self._warned_untrained:
                logger.warning(
                    "recovery_mode=ccdp but the recovery head is untrained (base-stage checkpoint): "
                    "sampling as plain DP. Train the recovery stage to use failures."
                )
                self._warned_untrained = True
            mode = "dp"
        streams = (
            None if self._streams is None else [self._streams[i] for i in rows.nonzero().flatten().tolist()]
        )
        plan = PlanRows(
            memory.state_condition(rows),
            memory.history_condition(rows),
            z,
            z_mask,
            None if noise is None else noise[rows],
            streams,
        )
        chunks = SAMPLERS[mode](self.model, plan)
        if not bool(torch.isfinite(chunks).all()):
            self._refuse_non_finite_plan(rows, chunks, plan, mode)
        return chunks

    def _refuse_non_finite_plan(self, rows: Tensor, chunks: Tensor, plan: PlanRows, mode: str) -> None:
        """Non-finite actions are never returned: name what made them (damaged tensors, non-finite
        failures, or settings that overflow eq. (4))."""
        bad = rows.nonzero().flatten()[~torch.isfinite(chunks).flatten(start_dim=1).all(dim=1)].tolist()
        damaged = [
            name
            for name, tensor in self.state_dict().items()
            if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all())
        ]
        weights = self.model.weights
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
                "defaults (w_s 1, w_z 1, w_h 0), and inputs within the training data's range"
            )
        raise FloatingPointError(
            f"The {mode} sampler made NaN or inf actions for row(s) {bad}; none were returned. Cause: "
            f"{cause}."
        )


# What `report_failure(rows=...)` takes.
ROW_FORMS = (
    "None (every row), a row index (int), a list or tensor of row indices, or a bool mask with one entry "
    "per row"
)


def _row_index(rows: object) -> Tensor | None:
    """`report_failure`'s rows as a tensor of row indices or a bool mask (None: every row), refusing any
    other type before anything is recorded."""
    if rows is None:
        return None
    refused = TypeError(
        f"report_failure(rows={rows!r}) got a {type(rows).__name__}; rows takes {ROW_FORMS}. For every "
        "row, leave rows out."
    )
    if isinstance(rows, (str, bytes, bool, float)):
        raise refused
    try:
        index = torch.as_tensor(rows)
    except (TypeError, ValueError, RuntimeError):
        raise refused from None
    if index.numel() == 0:  # an empty list of rows: nothing failed
        return index.long()
    if index.ndim > 1 or (index.dtype != torch.bool and (index.is_floating_point() or index.is_complex())):
        raise refused
    return index


class CCDPModel(nn.Module):
    """The base denoiser (eps_a, eps_s, eps_h in one network), the recovery head, the camera encoder, the
    outcome table and the noise schedule. `compute_loss` trains the stage the config names; `denoise` runs the
    reverse diffusion with eq. (4) (or the head's own composition) at every step."""

    def __init__(self, config: CCDPConfig, dataset_meta=None, dataset_stats=None):
        super().__init__()
        self.config = config
        self.base = BaseDenoiser(config)
        self.images = ImageEncoder(config) if config.image_features else None
        self.recovery = make_recovery_denoiser(config)
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
        if dataset_stats is not None and config.training_stage == "base":
            refuse_non_finite_stats(config, dataset_stats)
            self.constant_inputs.fill(config, dataset_stats)
        if (
            dataset_meta is not None
            and config.training_stage == "base"
            and config.failure_feature != "action"
        ):
            self.outcomes.fill(*build_outcome_table(config, dataset_meta, dataset_stats))
        self._set_trainable()

    # ----- training -------------------------------------------------------------------------------------

    def set_weights(self) -> None:
        """The weights of eq. (4), from the config (again after it was edited)."""
        c = self.config
        self.weights = CompositionWeights(c.w_s, c.w_h, c.w_z, c.z_reference, c.w_z_steps, c.w_z_from_step)

    def _set_trainable(self) -> None:
        """The recovery stage trains eps_z only: the base network and the camera encoder are frozen."""
        base_stage = self.config.training_stage == "base"
        self.base.requires_grad_(base_stage)
        if self.images is not None:
            self.images.requires_grad_(base_stage)
        self.recovery.requires_grad_(not base_stage)

    def compute_loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Loss of the stage the config names: the base denoiser on demos, or the recovery head on its
        dataset."""
        if self.config.training_stage == "base":
            return self._base_loss(batch)
        if self.config.recovery_head == "classifier":
            return self._failure_set_loss(batch)
        if self.config.recovery_head == "set_denoiser":
            return self._set_denoiser_loss(batch)
        return self._recovery_loss(batch)

    def _base_loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        cfg = self.config
        state, history, chunk, pad = self._windows(batch)
        b = chunk.shape[0]
        keep_s = (torch.rand(b, 1, device=chunk.device) >= P_DROP_STATE).float()
        keep_h = (torch.rand(b, 1, device=chunk.device) >= P_DROP_HISTORY).float() * float(
            cfg.history_length > 0
        )
        noise, timesteps, noisy = self._noised(chunk)
        loss = F.mse_loss(
            self.base(noisy, timesteps, state, keep_s, history, keep_h), noise, reduction="none"
        )
        if cfg.do_mask_loss_for_padding and pad is not None:
            loss = loss * ~pad[:, cfg.history_length :, None]
        return loss.mean(), {}

    def _windows(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        """A demonstration batch as the base sees it: state condition, history condition, the chunk to denoise
        and the chunk's padding flags (or None)."""
        cfg = self.config
        refuse_unknown_cameras(self.config, batch)
        frames = self.frames(batch)
        windows = (cfg.history_length + cfg.n_obs_steps, cfg.history_length + cfg.horizon)
        if (
            frames.ndim != 3
            or batch[ACTION].ndim != 3
            or (frames.shape[1], batch[ACTION].shape[1]) != windows
        ):
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

    def _failure_set_loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """The failure-set classifier on the demonstrated chunks. Each row gets a failure set F of 1 to
        FAILURE_SET_TRAIN_SIZE z drawn from other rows (so F is independent of the row's own chunk) and is a
        repeat when its own z lies within delta_z of a failure in F; the classifier learns P(repeat | a_t, s)
        with the base's noise schedule.
        The state is dropped as in the base (`_classifier_loss`)."""
        cfg = self.config
        state, _, chunk, _ = self._windows(batch)
        b, n = chunk.shape[0], FAILURE_SET_TRAIN_SIZE
        if b < 2:
            raise ValueError(
                "The classifier draws each row's failures from the other rows: use --batch_size >= 2."
            )
        self.recovery_trained.fill_(True)
        z_set, z_mask, repeats = draw_failure_sets(
            self.feature.from_chunk(chunk, self.outcomes), n, cfg.delta_z
        )
        _, timesteps, noisy = self._noised(chunk)
        return _classifier_loss(self.recovery, noisy, timesteps, state, z_set, z_mask, repeats), {}

    def _set_denoiser_loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """eps_{s,F} on the rows of a set-denoiser dataset: chunks the base samples at option starts and along
        the demonstrations, with their state (lerobot-ccdp-synthesize, `synthesize.set_denoiser_frames`). Each
        row gets a failure set F of 1..FAILURE_SET_TRAIN_SIZE z drawn from other rows (so F is independent of
        the row's own chunk); rows whose own z lies within delta_z of a failure in F are left out. The rows
        kept are p_s(a | s) q(F) 1[z(a) outside F], whose conditional given (s, F) is p_s restricted to the
        options outside F in the base's proportions: DP*'s rejection, distilled. The first step copies the
        base into the head (`FailureSetDenoiser.start_from`). The head's guard learns P(repeat | a_t, s, F) on
        the same noisy rows and failure sets, every row included, as the classifier head does."""
        cfg = self.config
        state, chunk = self.frames(batch), batch[ACTION]
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
        if not bool(self.recovery_trained):
            self.recovery.start_from(self.base)
            self.recovery_trained.fill_(True)
        z = self.feature.from_chunk(chunk, self.outcomes)
        if cfg.state_failure_sets:
            siblings, count = self._siblings(batch, f"--policy.state_failure_sets={cfg.state_failure_sets}")
            z_set, z_mask, repeats = draw_state_failure_sets(
                z, siblings, count, FAILURE_SET_TRAIN_SIZE, cfg.delta_z, cfg.state_failure_sets
            )
        else:
            z_set, z_mask, repeats = draw_failure_sets(z, FAILURE_SET_TRAIN_SIZE, cfg.delta_z)
        noise, timesteps, noisy = self._noised(chunk)
        loss = F.mse_loss(self.recovery(noisy, timesteps, state, z_set, z_mask), noise, reduction="none")
        kept = (~repeats).to(loss.dtype)
        if cfg.stratum_weights:
            siblings, count = self._siblings(batch, "--policy.stratum_weights=true")
            weight = kept * stratum_weights(z_set, z_mask, siblings, count, cfg.delta_z)
        else:
            weight = kept
        loss = (loss.mean(dim=(1, 2)) * weight).sum() / weight.sum().clamp_min(1.0)
        guard_loss = _classifier_loss(self.recovery.guard, noisy, timesteps, state, z_set, z_mask, repeats)
        self.recovery.guard_trained.fill_(True)
        return loss + guard_loss, {"kept_rows": float(kept.mean()), "guard_loss": guard_loss.item()}

    def _siblings(self, batch: dict[str, Tensor], option: str) -> tuple[Tensor, Tensor]:
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

    def _recovery_loss(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        cfg = self.config
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
        self.recovery_trained.fill_(True)
        noise, timesteps, noisy = self._noised(chunk)
        keep_z = (torch.rand(chunk.shape[0], 1, device=chunk.device) >= P_DROP_FAILURE).to(z.dtype)
        return F.mse_loss(self.recovery(noisy, timesteps, z, keep_z), noise), {}

    def _noised(self, chunk: Tensor) -> tuple[Tensor, Tensor, Tensor]:
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
        return self.denoise(
            noise,
            state,
            history,
            no_failures,
            no_failures[..., 0].bool(),
            CompositionWeights.exploration(w_s),
        )

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
        one base call and at most one recovery call per step, whatever the number of failures. With the
        classifier head the failures enter by guidance instead (`guide_away_from_failures`); with the set
        denoiser, by its single failure-set term (`compose_with_failure_set`). The reverse steps' noise comes
        from `generators` (one per row, `noise_streams`) when given, else from torch's global generator."""
        weights = weights or self.weights
        self.noise_scheduler.set_timesteps(self.config.num_inference_steps or self.config.num_train_timesteps)
        timesteps = [int(t) for t in self.noise_scheduler.timesteps]
        if z.shape[1] and self.config.recovery_head == "set_denoiser":
            estimate = self._failure_set_estimate(weights, state, history, z, z_mask, timesteps)
        else:
            estimate = self._composed_estimate(weights, state, history, z, z_mask)
        for t in timesteps:
            eps = estimate(sample, t)
            sample = self.noise_scheduler.step(eps, t, sample, generator=generators).prev_sample
        return sample

    def _base_estimates(self, terms: list[str], state: Tensor, history: Tensor):
        """A function of (noisy sample, timestep) giving the base network's `terms` ("a": eps_a, "s": eps_s,
        "h": eps_h) for every row, in one call with the conditions repeated once per term."""
        r, k = state.shape[0], len(terms)
        if not k or not r:
            return lambda sample, t: {}
        ones, zeros = torch.ones(r, 1, device=state.device), torch.zeros(r, 1, device=state.device)
        keep = {"a": (zeros, zeros), "s": (ones, zeros), "h": (zeros, ones)}
        state_rows, history_rows = state.repeat(k, 1), history.repeat(k, 1)
        keep_s = torch.cat([keep[term][0] for term in terms])
        keep_h = torch.cat([keep[term][1] for term in terms])

        def estimates(sample: Tensor, t: int) -> dict[str, Tensor]:
            step = torch.full((r * k,), t, dtype=torch.long, device=sample.device)
            eps = self.base(sample.repeat(k, 1, 1), step, state_rows, keep_s, history_rows, keep_h)
            return dict(zip(terms, eps.split(r), strict=True))

        return estimates

    def _composed_estimate(
        self, weights: CompositionWeights, state: Tensor, history: Tensor, z: Tensor, z_mask: Tensor
    ):
        """eq. (4) with one term per failure (eps_z heads), or the classifier's guidance, as a function of
        (noisy sample, timestep)."""
        n = z.shape[1]
        guided = n > 0 and self.config.recovery_head == "classifier"
        base = self._base_estimates(weights.base_terms(z_mask.sum(dim=1) * (not guided)), state, history)
        z_rows, keep_z = recovery_conditions(z, weights.measures_against_z_null)
        failed = z_mask.any(dim=1)

        def estimate(sample: Tensor, t: int) -> Tensor:
            by_term = base(sample, t)
            if not guided:  # eps_z of every failure slot: the failures enter eq. (4)
                eps_z, eps_z_null = self._recovery_terms(sample, t, z_rows, keep_z, n) if n else (None, None)
                return compose_eps(
                    weights, by_term.get("a"), by_term.get("s"), by_term.get("h"), eps_z, z_mask, eps_z_null
                )
            composed = compose_eps(weights, by_term.get("a"), by_term.get("s"), by_term.get("h"))
            if guided and failed.any():
                step = torch.full((int(failed.sum()),), t, dtype=torch.long, device=sample.device)
                gradient = torch.zeros_like(sample)
                gradient[failed] = self._no_repeat_gradient(
                    self.recovery, sample[failed], step, state[failed], z[failed], z_mask[failed]
                )
                alpha_bar = self.noise_scheduler.alphas_cumprod[t].to(sample.device)
                composed = guide_away_from_failures(composed, gradient, alpha_bar, weights.w_z)
            return composed

        return estimate

    def _failure_set_estimate(
        self,
        weights: CompositionWeights,
        state: Tensor,
        history: Tensor,
        z: Tensor,
        z_mask: Tensor,
        timesteps: list[int],
    ):
        """`compose_with_failure_set` for the rows with failures (eps_{s,F} in one recovery call, plus the
        base terms whose coefficient is not zero at that step's weights: none at w_s = w_z = 1, w_h = 0),
        guided by the head's guard in the last `failure_guard_steps` steps (`guide_away_from_failures` at
        `failure_guard_weight`), and the base composition for the other rows as a function of (noisy sample,
        timestep)."""
        guarded = set(timesteps[len(timesteps) - self.config.failure_guard_steps :])
        if guarded and not bool(self.recovery.guard_trained):
            raise ValueError(
                f"--policy.failure_guard_steps={self.config.failure_guard_steps} follows the set denoiser's "
                "guard, which this checkpoint never trained (saved before the guard existed): set "
                "--policy.failure_guard_steps=0, or train the recovery stage again."
            )
        failed = z_mask.any(dim=1)
        no_failures = z[:, :0], z_mask[:, :0]
        plain_rest = self._composed_estimate(
            weights, state[~failed], history[~failed], no_failures[0][~failed], no_failures[1][~failed]
        )
        step_weights = {t: weights.at_step(index) for index, t in enumerate(timesteps)}
        base = {
            w: self._base_estimates(w.failure_set_base_terms(), state[failed], history[failed])
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
                "sF": self.recovery(noisy, step, state_failed, z_failed, mask_failed)
            }
            eps[failed] = compose_with_failure_set(step_weights[t], estimates)
            if t in guarded:
                gradient = self._no_repeat_gradient(
                    self.recovery.guard, noisy, step, state_failed, z_failed, mask_failed
                )
                alpha_bar = self.noise_scheduler.alphas_cumprod[t].to(sample.device)
                eps[failed] = guide_away_from_failures(
                    eps[failed], gradient, alpha_bar, self.config.failure_guard_weight
                )
            return eps

        return estimate

    def _recovery_terms(
        self, sample: Tensor, t: int, z_rows: Tensor, keep_z: Tensor, n: int
    ) -> tuple[Tensor, Tensor | None]:
        """eps_z(z_i) for every failure slot (R, N, horizon, A) and, when `z_rows` ends with the z-dropped
        rows, eps_z_null (R, horizon, A): one recovery call for all of them."""
        r, chunk = sample.shape[0], sample.shape[1:]
        noisy = sample[:, None].expand(r, n, *chunk).reshape(r * n, *chunk)
        null_row = z_rows.shape[0] > r * n
        if null_row:
            noisy = torch.cat([noisy, sample])
        step = torch.full((noisy.shape[0],), t, dtype=torch.long, device=sample.device)
        eps = self.recovery(noisy, step, z_rows, keep_z)
        return eps[: r * n].view(r, n, *chunk), (eps[r * n :] if null_row else None)

    def _no_repeat_gradient(
        self, classifier: nn.Module, sample: Tensor, step: Tensor, state: Tensor, z: Tensor, z_mask: Tensor
    ) -> Tensor:
        """grad_{a_t} log P(a_0 outside F | a_t, s) from a failure-set classifier (the classifier head or the
        set denoiser's guard). LeRobot samples under torch.inference_mode(), where no gradient exists: the
        inputs are copied into ordinary tensors first."""
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
            log_outside = log_no_repeat(
                logits.view(rows, n), distinct_failures(z, z_mask, self.config.delta_z)
            )
            (gradient,) = torch.autograd.grad(log_outside.sum(), noisy)
        return gradient

    # ----- inputs ---------------------------------------------------------------------------------------

    def frames(self, batch: dict[str, Tensor]) -> Tensor:
        """Observation frames (B, [T,] frame_dim) as the networks see them
        (`observations.observation_frames`)."""
        return observation_frames(self.config, self.images, batch, self.constant_inputs)


def _classifier_loss(
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
