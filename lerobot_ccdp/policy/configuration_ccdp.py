"""Configuration of the CCDP policy: LeRobot's diffusion settings plus the composition of eq. (4)."""

import math
from dataclasses import dataclass, field, fields
from pathlib import Path

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
from lerobot.optim.optimizers import AdamConfig
from lerobot.optim.schedulers import DiffuserSchedulerConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE

RECOVERY_MODES = ("ccdp", "dp", "dp_star")
FAILURE_FEATURES = ("final_state", "action", "primitive")
FAILURE_STATES_AT = ("attempt_end", "demonstrated_end")
FAILURE_SEGMENTS = ("labels", "releases", "drops", "pauses")
TRAINING_STAGES = ("base", "recovery")
RECOVERY_HEADS = ("unet", "mlp", "classifier", "set_denoiser")
CLASSIFIER_CHUNKS = ("demonstrations", "base_samples")
CLASSIFIER_QUERIES = ("set", "each")
Z_REFERENCES = ("eps_a", "eps_z_null")
# Counts and sizes that must be >= 1, and those that must be >= 0 (`_check_numbers`).
POSITIVE_FIELDS = ("n_obs_steps", "horizon", "n_action_steps", "num_train_timesteps", "num_inference_steps",
                   "kernel_size", "diffusion_step_embed_dim", "spatial_softmax_num_keypoints",
                   "max_failures", "dp_star_candidates", "dp_star_rounds", "failure_set_train_size",
                   "classifier_resample_every", "outcome_index_size", "recovery_hidden_dim", "recovery_num_blocks")
NON_NEGATIVE_FIELDS = ("delta_z", "history_length", "ccdp_redraws", "scheduler_warmup_steps")
# Column holding the failure feature z in recovery datasets, and the policy input it becomes.
FAILURE_FEATURE_KEY = "observation.failure_feature"
# Observation key an env uses to flag a failed attempt (DESIGN section 5).
FAILURE_FLAG_KEY = "observation.failure"


@PreTrainedConfig.register_subclass("ccdp")
@dataclass
class CCDPConfig(PreTrainedConfig):
    """CCDP = LeRobot's diffusion policy composed at sampling time with failure-conditioned recovery heads.

    The base UNet is trained once with condition dropout so that one network yields the unconditional
    (eps_a), state-conditioned (eps_s) and history-conditioned (eps_h) noise estimates; the recovery head
    (eps_z) is trained in a second stage on a synthesised recovery dataset. Both stages use this config:
    `training_stage` selects what `forward()` trains.

    Defaults are sized for low-dimensional tasks on a 2-core CPU (a 1.1 M-parameter UNet, 10 inference steps,
    a learning rate and warm-up that converge in a few thousand steps). The reverse step is DDPM's stochastic
    one, eq. (3) of the paper: deterministic DDIM follows eq. (4)'s summed estimates exactly and so keeps their
    error, which lets remembered failures back in (README, "Reverse sampler").
    """

    # Diffusion (same meaning as in LeRobot's DiffusionConfig).
    n_obs_steps: int = 1
    horizon: int = 16
    n_action_steps: int = 8
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.MEAN_STD,
            "STATE": NormalizationMode.MIN_MAX,
            "ENV": NormalizationMode.MIN_MAX,
            "ACTION": NormalizationMode.MIN_MAX,
        }
    )
    # Vision (same fields and defaults as LeRobot's DiffusionConfig; its RGB encoder is reused as is). The backbone
    # is randomly initialised unless `pretrained_backbone_weights` names torchvision weights (e.g.
    # "ResNet18_Weights.IMAGENET1K_V1"), which torchvision must find in its cache or download.
    vision_backbone: str = "resnet18"
    # ResNet stages kept (4 = LeRobot's encoder). Each stage halves the feature map: 3 keeps a 4x4 map of 64 px
    # images for the spatial softmax (4 stages leave 2x2) at a quarter of the backbone's parameters.
    vision_backbone_stages: int = 4
    resize_shape: tuple[int, int] | None = None
    crop_ratio: float = 1.0
    crop_shape: tuple[int, int] | None = None
    crop_is_random: bool = True
    pretrained_backbone_weights: str | None = None
    use_group_norm: bool = True
    spatial_softmax_num_keypoints: int = 32
    use_separate_rgb_encoder_per_camera: bool = False
    # UNet.
    down_dims: tuple[int, ...] = (32, 64, 128)
    kernel_size: int = 5
    n_groups: int = 8
    diffusion_step_embed_dim: int = 32
    use_film_scale_modulation: bool = True
    noise_scheduler_type: str = "DDPM"
    num_train_timesteps: int = 100
    num_inference_steps: int | None = 10
    beta_schedule: str = "squaredcos_cap_v2"
    beta_start: float = 0.0001
    beta_end: float = 0.02
    prediction_type: str = "epsilon"
    clip_sample: bool = True
    clip_sample_range: float = 1.0
    do_mask_loss_for_padding: bool = False

    # Composition weights of eq. (4). A zero weight skips that term's network rows.
    w_s: float = 1.0
    w_h: float = 0.0
    w_z: float = 1.0
    # What each failure term of eq. (4) is measured against: "eps_a" (the paper) or "eps_z_null" (the recovery
    # head with z dropped, trained on the same recovery data as eps_z; see compose_eps).
    z_reference: str = "eps_z_null"
    # Share of the reverse steps, counted from the noisiest, whose estimate includes the failures (eq. 4's failure
    # terms, or the classifier's guidance). The noisy steps choose the option; in the remaining low-noise steps the
    # base alone refines the chunk within it, so the recovery model's error does not move where the chunk ends.
    # 1.0, the default, is the paper: failures at every step.
    failure_step_share: float = 1.0
    # History h_t^H: the H states and actions before the current observation window.
    history_length: int = 2
    # Condition dropout while training the base network (independent per condition): dropping both
    # conditions trains eps_a, dropping one trains eps_s or eps_h.
    p_drop_state: float = 0.3
    p_drop_history: float = 0.5

    # Recovery.
    recovery_mode: str = "ccdp"
    failure_feature: str = "final_state"
    # final_state: which observation and which of its dims form z (empty = all dims).
    failure_state_key: str = OBS_STATE
    failure_state_dims: list[int] = field(default_factory=list)
    # final_state: where a failure's z is read. "attempt_end": the observed state where the failed attempt stopped.
    # "demonstrated_end": the final state of the demonstration whose chunk is nearest the one executing when the
    # failure was flagged, i.e. where the attempt was heading. The second matches the z the recovery head trained
    # on when a failure is flagged mid-option (a pick that slips 4 cm above the box ends nowhere a pick is
    # demonstrated to end); it needs the outcome table, as `primitive` does.
    failure_state_at: str = "attempt_end"
    # final_state: where a demonstrated option ends (lerobot_ccdp/recovery/demo_segments.py), which gives each demonstrated
    # chunk its final state. "labels": runs of one `primitive_key` label, the whole episode without that column.
    # Label-free: "releases" (the gripper command, action dim `gripper_action_dim`, lets go), "drops" (a release and
    # the still frames after it, while the hand opens) or "pauses" (the action holds still, changing less than
    # `pause_tolerance` in normalised units, for `pause_steps` frames).
    failure_segments: str = "labels"
    gripper_action_dim: int = -1
    pause_steps: int = 2
    pause_tolerance: float = 1e-3
    # action: which steps of the attempt's first chunk, and which action dims at each, form z (empty = all). Dims
    # that spread within an option (the box: where along it the hand goes) would hide which option it was.
    failure_action_steps: list[int] = field(default_factory=list)
    failure_action_dims: list[int] = field(default_factory=list)
    # primitive: the dataset column holding the per-frame primitive label, and how many labels exist.
    primitive_key: str = "primitive"
    num_primitives: int = 0
    # A file whose appearance or touch reports a failure of every row, for LeRobot loops such as lerobot-record
    # that pass the policy no failure signal (lerobot_ccdp/policy/failure_signal.py). A run-time setting of the machine
    # the policy acts on: never saved in a checkpoint, and a loaded checkpoint's value is ignored.
    failure_signal_file: str | None = None
    # Most failures remembered per batch row; the oldest is forgotten beyond it.
    max_failures: int = 8
    # DP*: candidates drawn per plan, and the squared distance in z under which a candidate repeats a failure.
    delta_z: float = 0.1
    dp_star_candidates: int = 16
    # DP*: rounds of `dp_star_candidates` fresh candidates drawn for a row whose candidates were all rejected,
    # before it falls back to the candidate farthest from every failure (1 = no redraw). A redraw costs time
    # only where every candidate repeats a failure; with one round, one-hot z made the fallback a repeat.
    dp_star_rounds: int = 4
    # CCDP: plans redrawn, at most this many times, where the chunk CCDP sampled still repeats a failure (its outcome
    # looked up as DP* looks up its candidates'). 0, the default, is the method itself: one sample per plan. Above 0
    # the kept chunks follow CCDP's distribution restricted to the options that did not fail, at the cost of one more
    # denoising pass for the few rows that repeated (`dp_star.reject_repeats` with one candidate per round).
    ccdp_redraws: int = 0
    # Where a plan's noise comes from. False, LeRobot's diffusion behaviour: torch's global generator. True: each
    # batch row of each rollout has its own generator, seeded from torch's seed (lerobot-eval's --seed), the rollout's
    # index and the row (`noise_streams`), for a plan's first sample (DP*'s first candidate, CCDP's first draw). DP,
    # DP* and CCDP evaluated with the same --seed then draw the same noise for the same episode, so they act alike
    # until its first failure (common random numbers); `make benchmark` evaluates every method so.
    row_noise_streams: bool = False
    # Demonstrated chunks kept to look up the outcome (final state, primitive) of a sampled chunk.
    outcome_index_size: int = 20000
    # Recovery head: "unet" (eps_z, LeRobot's diffusion UNet conditioned on z, trained on a synthesised recovery
    # dataset), "mlp" (eps_z as a residual MLP over the flattened chunk, FiLM-conditioned on z: cheaper, less sharp)
    # or "classifier" (a noisy-chunk classifier of "repeats a failure of the set F" given the state, trained on the
    # demonstrations themselves, whose gradient guides eps_s; composition.guide_away_from_failures) or "set_denoiser"
    # (eps_{s,F}: a copy of the base UNet conditioned on the state and the whole failure set F, trained on chunks the
    # base samples where attempts start (lerobot-ccdp-synthesize) with F drawn independently of each row and the rows
    # whose own outcome lies in F left out: it learns p_s restricted to the options outside F, one network call per
    # step whatever the number of failures; composition.compose_with_failure_set). The size of the MLP heads and of the set embedding, and the most
    # failures drawn for one training row of the classifier and the set denoiser.
    recovery_head: str = "unet"
    recovery_hidden_dim: int = 128
    recovery_num_blocks: int = 3
    failure_set_train_size: int = 3
    # What the failure-set classifier learns from: the demonstrated chunks ("demonstrations": guidance then keeps the
    # demonstrations' proportions among the options left) or chunks the frozen base samples at the batch's states,
    # labelled through the outcome table ("base_samples": it keeps the base policy's own proportions, what DP* keeps;
    # from a pool refreshed with a batch of base samples every `classifier_resample_every` steps).
    classifier_chunks: str = "demonstrations"
    classifier_resample_every: int = 4
    # How sampling asks the classifier about the failures: "each" (one query per distinct failure, P(outside F) =
    # 1 - sum_i P(repeats z_i): exact for disjoint options, and it asks only about single failures, which every
    # training row's set can be; composition.log_no_repeat) or "set" (one query with the whole set F). A sampling
    # setting: the same trained classifier serves both. "each" kept the base's proportions better on the 2-D
    # family's development members (docs/benchmarks.md).
    classifier_query: str = "each"
    # z dropout while training the recovery head, so that it also yields eps_z_null.
    p_drop_failure: float = 0.1

    training_stage: str = "base"

    # Training presets.
    optimizer_lr: float = 1e-3
    optimizer_betas: tuple = (0.95, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-6
    scheduler_name: str = "cosine"
    scheduler_warmup_steps: int = 100

    def __post_init__(self):
        super().__post_init__()
        self._check_numbers()
        if self.prediction_type != "epsilon":
            raise ValueError(
                f"CCDP composes noise estimates (eq. 4), so `prediction_type` must be 'epsilon'; got "
                f"{self.prediction_type!r}. Remove --policy.prediction_type or set it to epsilon."
            )
        for name in ("w_s", "w_h", "w_z"):
            if getattr(self, name) < 0:
                raise ValueError(f"`{name}` must be >= 0 (eq. 4 uses positive weights); got {getattr(self, name)}.")
        for name in ("p_drop_state", "p_drop_history", "p_drop_failure"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ValueError(f"`{name}` must be in [0, 1); got {getattr(self, name)}.")
        self._check_choice("recovery_mode", RECOVERY_MODES)
        self._check_choice("failure_feature", FAILURE_FEATURES)
        self._check_choice("failure_state_at", FAILURE_STATES_AT)
        self._check_choice("failure_segments", FAILURE_SEGMENTS)
        if self.pause_steps < 1 or self.pause_tolerance < 0:
            raise ValueError(f"`pause_steps` must be >= 1 and `pause_tolerance` >= 0; got {self.pause_steps} and "
                             f"{self.pause_tolerance}.")
        self._check_choice("training_stage", TRAINING_STAGES)
        self._check_choice("recovery_head", RECOVERY_HEADS)
        self._check_choice("classifier_chunks", CLASSIFIER_CHUNKS)
        self._check_choice("classifier_query", CLASSIFIER_QUERIES)
        self._check_choice("z_reference", Z_REFERENCES)
        self._check_choice("noise_scheduler_type", ("DDPM", "DDIM"))
        self._check_vision()
        if self.failure_state_key not in (OBS_STATE, OBS_ENV_STATE):
            raise ValueError(
                f"`failure_state_key` must be {OBS_STATE!r} or {OBS_ENV_STATE!r}; got {self.failure_state_key!r}."
            )
        if self.failure_feature == "primitive" and self.num_primitives < 2:
            raise ValueError(
                "failure_feature='primitive' needs `num_primitives` >= 2 (the number of distinct labels in "
                f"the dataset column {self.primitive_key!r}); got {self.num_primitives}."
            )
        bad_steps = [s for s in self.failure_action_steps if not 0 <= s < self.horizon]
        if bad_steps:
            raise ValueError(f"`failure_action_steps` {bad_steps} fall outside the chunk [0, {self.horizon}).")
        if not 0.0 < self.failure_step_share <= 1.0:
            raise ValueError(f"`failure_step_share` must be in (0, 1] (1: failures at every reverse step); got "
                             f"{self.failure_step_share}. For no failures at all use --policy.recovery_mode=dp.")
        if self.recovery_head == "set_denoiser" and self.n_obs_steps != 1:
            raise ValueError(f"recovery_head='set_denoiser' trains on one-frame rows of a synthesised dataset: it needs "
                             f"n_obs_steps=1; got {self.n_obs_steps}. Use --policy.recovery_head=unet.")
        if self.horizon % 2 ** len(self.down_dims) != 0:
            raise ValueError(
                f"`horizon` ({self.horizon}) must be a multiple of 2**len(down_dims) = {2 ** len(self.down_dims)}."
            )
        if self.n_action_steps > self.horizon - self.n_obs_steps + 1:
            raise ValueError(
                f"`n_action_steps` ({self.n_action_steps}) must be <= horizon - n_obs_steps + 1 "
                f"({self.horizon - self.n_obs_steps + 1})."
            )

    def _save_pretrained(self, save_directory: Path) -> None:
        """Save without `failure_signal_file`: a path on this machine is no part of the model, and a checkpoint
        someone else loads must not choose a file for their policy to watch."""
        signal, self.failure_signal_file = self.failure_signal_file, None
        try:
            super()._save_pretrained(save_directory)
        finally:
            self.failure_signal_file = signal

    def _check_numbers(self) -> None:
        """Every number finite, and the sizes of a chunk positive: NaN passes every `<` check (a NaN weight gave NaN
        actions that lerobot-eval scored as failed episodes, a NaN delta_z a DP* that never rejects), and
        n_action_steps 0 trains, then fails at the first action."""
        for f in fields(self):
            value = getattr(self, f.name)
            values = value if isinstance(value, (list, tuple)) else [value]
            if any(isinstance(v, float) and not math.isfinite(v) for v in values):
                raise ValueError(f"`{f.name}` must be a finite number; got {value}. Set --policy.{f.name} to a "
                                 "number (its default is in `lerobot-train --policy.type=ccdp --help`).")
        at_least = {name: 1 for name in POSITIVE_FIELDS} | {name: 0 for name in NON_NEGATIVE_FIELDS}
        small = {name: getattr(self, name) for name, low in at_least.items()
                 if getattr(self, name) is not None and getattr(self, name) < low}
        small |= {"down_dims": self.down_dims} if not self.down_dims or min(self.down_dims) < 1 else {}
        if small:
            raise ValueError(f"{', '.join(f'`{k}`' for k in small)} must be >= 1 (`delta_z`, `history_length`, "
                             f"`ccdp_redraws` and `scheduler_warmup_steps` >= 0, `down_dims` non-empty); got {small}.")
        if self.num_inference_steps is not None and self.num_inference_steps > self.num_train_timesteps:
            raise ValueError(f"`num_inference_steps` ({self.num_inference_steps}) cannot exceed `num_train_timesteps` "
                             f"({self.num_train_timesteps}): the reverse diffusion visits training timesteps.")

    def _check_vision(self) -> None:
        """The checks LeRobot's DiffusionConfig makes of the same fields, and its crop derivation."""
        if not self.vision_backbone.startswith("resnet"):
            raise ValueError(f"`vision_backbone` must be a torchvision ResNet (e.g. resnet18); got {self.vision_backbone!r}.")
        if self.resize_shape is not None and (len(self.resize_shape) != 2 or min(self.resize_shape) <= 0):
            raise ValueError(f"`resize_shape` must be a pair of positive integers; got {self.resize_shape}.")
        if self.vision_backbone_stages not in (1, 2, 3, 4):
            raise ValueError(f"`vision_backbone_stages` must be 1 to 4 (a ResNet has 4); got {self.vision_backbone_stages}.")
        if not 0 < self.crop_ratio <= 1.0:
            raise ValueError(f"`crop_ratio` must be in (0, 1]; got {self.crop_ratio}.")
        if self.resize_shape is not None:
            ratio = self.crop_ratio
            self.crop_shape = None if ratio == 1.0 else tuple(int(d * ratio) for d in self.resize_shape)
        if self.crop_shape is not None and min(self.crop_shape) <= 0:
            raise ValueError(f"`crop_shape` must have positive dimensions; got {self.crop_shape}.")
        if self.use_group_norm and self.pretrained_backbone_weights:
            raise ValueError(
                "Pretrained backbone weights were trained with BatchNorm: set --policy.use_group_norm=false "
                "to use them (replacing BatchNorm by GroupNorm would discard what they learnt)."
            )

    def _check_choice(self, name: str, allowed: tuple[str, ...]) -> None:
        if getattr(self, name) not in allowed:
            raise ValueError(f"Unknown `{name}` {getattr(self, name)!r}; choose one of {list(allowed)}.")

    def validate_features(self) -> None:
        """Check the dataset/env features against what the policy needs, and declare the z input."""
        if self.robot_state_feature is None:
            raise ValueError(
                f"CCDP needs {OBS_STATE!r} among the input features; the dataset or env has "
                f"{sorted(self.input_features)}. Record the robot state as {OBS_STATE!r}."
            )
        self._validate_images()
        if self.image_features and self.recovery_head == "set_denoiser":
            raise ValueError("recovery_head='set_denoiser' conditions on the state of synthesised rows, which carry no "
                             "camera images yet: use --policy.recovery_head=unet with cameras.")
        if self.action_feature is None:
            raise ValueError(f"CCDP needs an {ACTION!r} output feature; the dataset has none.")
        if len(self.action_feature.shape) == 2:
            # Recovery datasets store one chunk per frame: (horizon, action_dim). The policy acts per step.
            self.output_features[ACTION] = PolicyFeature(FeatureType.ACTION, self.action_feature.shape[-1:])
        if self.failure_feature == "final_state":
            source = self.input_features.get(self.failure_state_key)
            if source is None:
                raise ValueError(
                    f"failure_feature='final_state' reads {self.failure_state_key!r}, which the dataset lacks; "
                    f"choose --policy.failure_state_key among {sorted(self.input_features)}."
                )
            bad = [d for d in self.failure_state_dims if not 0 <= d < source.shape[0]]
            if bad:
                raise ValueError(
                    f"`failure_state_dims` {bad} do not exist in {self.failure_state_key!r} "
                    f"(shape {tuple(source.shape)})."
                )
        action_dim = self.action_feature.shape[-1]
        bad = [d for d in self.failure_action_dims if not 0 <= d < action_dim]
        if self.failure_feature == "action" and bad:
            raise ValueError(f"`failure_action_dims` {bad} do not exist in the {action_dim}-dim action.")
        if self.failure_segments in ("releases", "drops") and not -action_dim <= self.gripper_action_dim < action_dim:
            raise ValueError(
                f"`gripper_action_dim` {self.gripper_action_dim} does not exist in the {action_dim}-dim action; "
                "set --policy.gripper_action_dim to the gripper command's index."
            )
        self.input_features[FAILURE_FEATURE_KEY] = PolicyFeature(FeatureType.STATE, (self.failure_feature_dim,))

    def _validate_images(self) -> None:
        """Every camera has the same (C, H, W) shape (one encoder shape, as in LeRobot) and fits the crop."""
        shapes = {key: tuple(ft.shape) for key, ft in self.image_features.items()}
        if len(set(shapes.values())) > 1:
            raise ValueError(
                f"All cameras must have the same shape (one encoder input size); got {shapes}. Record them at one "
                "size, or set --policy.resize_shape=[H,W] to resize every camera to it."
            )
        if shapes and self.crop_shape is not None and self.resize_shape is None:
            _, height, width = next(iter(shapes.values()))
            if self.crop_shape[0] > height or self.crop_shape[1] > width:
                raise ValueError(f"`crop_shape` {self.crop_shape} does not fit in the camera images {shapes}.")

    @property
    def state_dim(self) -> int:
        """Size of the low-dimensional part of an observation frame (robot state + environment state)."""
        env = self.env_state_feature.shape[0] if self.env_state_feature else 0
        return self.robot_state_feature.shape[0] + env

    @property
    def image_feature_dim(self) -> int:
        """Size of the encoded cameras of one frame: 2 coordinates per spatial-softmax keypoint and camera."""
        return len(self.image_features) * 2 * self.spatial_softmax_num_keypoints

    @property
    def frame_dim(self) -> int:
        """Size of one observation frame as the networks see it: low-dimensional state, then camera features."""
        return self.state_dim + self.image_feature_dim

    @property
    def action_dim(self) -> int:
        return self.action_feature.shape[-1]

    @property
    def failure_feature_dim(self) -> int:
        if self.failure_feature == "final_state":
            return len(self.failure_state_dims) or self.input_features[self.failure_state_key].shape[0]
        if self.failure_feature == "action":
            return (len(self.failure_action_steps) or self.horizon) * (len(self.failure_action_dims) or self.action_dim)
        return self.num_primitives

    @property
    def trains_on_windows(self) -> bool:
        """Whether this stage reads demonstration windows (the base, and the heads that learn from the demos too)
        rather than whole recovery rows of a synthesised dataset."""
        return self.training_stage == "base" or self.recovery_head_learns_from_demonstrations

    @property
    def recovery_head_learns_from_demonstrations(self) -> bool:
        """Whether the recovery head trains on the demonstrations themselves (no synthesised recovery dataset)."""
        return self.recovery_head == "classifier"

    @property
    def drop_n_last_frames(self) -> int:
        """Frames at an episode's end that cannot start a full chunk (windows); recovery rows are whole."""
        if not self.trains_on_windows:
            return 0
        return self.horizon - self.n_action_steps - self.n_obs_steps + 1

    @property
    def observation_delta_indices(self) -> list | None:
        if not self.trains_on_windows:
            return None
        return list(range(1 - self.n_obs_steps - self.history_length, 1))

    @property
    def action_delta_indices(self) -> list | None:
        if not self.trains_on_windows:
            return None
        start = 1 - self.n_obs_steps - self.history_length
        return list(range(start, 1 - self.n_obs_steps + self.horizon))

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> AdamConfig:
        return AdamConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
        )

    def get_scheduler_preset(self) -> DiffuserSchedulerConfig:
        return DiffuserSchedulerConfig(name=self.scheduler_name, num_warmup_steps=self.scheduler_warmup_steps)
