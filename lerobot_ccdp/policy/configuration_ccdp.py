"""Configuration of the CCDP policy: LeRobot's diffusion settings plus the composition of eq. (4)."""

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
from lerobot.optim.optimizers import AdamConfig
from lerobot.optim.schedulers import DiffuserSchedulerConfig
from lerobot.utils.constants import ACTION

from lerobot_ccdp.compat.literal_choices import choices
from lerobot_ccdp.policy.config_checks import check_features, check_settings

RecoveryMode = Literal["ccdp", "dp", "dp_star"]
FailureFeatureKind = Literal["final_state", "action", "primitive"]
FailureStateAt = Literal["attempt_end", "demonstrated_end"]
FailureLabelAt = Literal["latest_chunk", "attempt_end"]
FailureSegments = Literal["labels", "drops", "pauses"]
TrainingStage = Literal["base", "recovery"]
RecoveryHead = Literal["unet", "classifier", "set_denoiser"]
# `recovery_head`'s values: a head, or "auto", the default head for the inputs (`heads.head_of`).
RecoveryHeadSetting = Literal["auto", RecoveryHead]
# Each Literal's values; `choices` also gives draccus a decoder for it (compat/literal_choices.py), which
# every field of these types needs. `config_checks` reads the allowed values from the fields' types.
RECOVERY_MODES = choices(RecoveryMode)
FAILURE_FEATURES = choices(FailureFeatureKind)
FAILURE_STATES_AT = choices(FailureStateAt)
FAILURE_LABELS_AT = choices(FailureLabelAt)
FAILURE_SEGMENTS = choices(FailureSegments)
TRAINING_STAGES = choices(TrainingStage)
RECOVERY_HEADS = choices(RecoveryHead)
RECOVERY_HEAD_SETTINGS = choices(RecoveryHeadSetting)
# Column holding the failure feature z in recovery datasets, and the policy input it becomes.
FAILURE_FEATURE_KEY = "observation.failure_feature"
# Set-denoiser datasets: the outcomes of every chunk sampled at a row's state (the policy's normalised z; no
# policy feature names them, so the preprocessor passes them through) and how many of them are real.
SIBLING_FEATURES_KEY = "observation.failure_feature_siblings"
SIBLING_COUNT_KEY = "observation.failure_feature_sibling_count"
# Observation key an env uses to flag a failed attempt (DESIGN section 5).
FAILURE_FLAG_KEY = "observation.failure"
# Fourier octaves of a point z (`final_state`) by default: the label-free buttons and Bartender gained 0.09 of
# success with 4, the door, box, packing and the 2-D family tied (docs/benchmarks.md, "Label-free z").
FOURIER_OCTAVES_OF_A_POINT = 4


@PreTrainedConfig.register_subclass("ccdp")
@dataclass
class CCDPConfig(PreTrainedConfig):
    """CCDP = LeRobot's diffusion policy composed at sampling time with a recovery model of the failures.

    The base UNet is trained once with condition dropout, so that one network yields the unconditional
    (eps_a), state-conditioned (eps_s) and history-conditioned (eps_h) noise estimates; the recovery head is
    trained in a second stage (`training_stage=recovery`) from the base's checkpoint. The diffusion, vision
    and optimizer fields mean what they mean in LeRobot's DiffusionConfig; their defaults are sized for
    low-dimensional tasks on a 2-core CPU (a 1.1 M-parameter UNet, 10 DDPM steps). The reverse step is DDPM's
    stochastic one, eq. (3) of the paper (docs/method.md, "Reverse sampler").

    The defaults of the sampling settings (`w_z`, `w_z_steps`, the guard's `failure_guard_*`, `dp_star_*`,
    `row_noise_streams`) are the benchmark's one configuration for every task, chosen on its development seeds
    (docs/benchmarks.md, "The one configuration"), so `lerobot-eval` on a checkpoint evaluates the CCDP and
    DP* the pipeline does; docs/results.md's rounds name the forms they measured. Eq. (4)'s state weight is 1
    (the base's own eps_s: `CompositionWeights`).

    Args:
        w_h: Weight of the history term eps_h - eps_a in eq. (4); needs `history_length` > 0. Every weight
            (w_h, w_z, failure_guard_weight) lies in [0, 100]: beyond, every action sits on its clipping bound
            (`config_checks.MAX_WEIGHT`).
        w_z: Weight of the failure terms of eq. (4), or of the failure-set term for the set denoiser and the
            classifier's guidance.
        w_z_steps: Set denoiser: apply `w_z` only at the `w_z_steps` noisiest reverse steps (where a sample
            picks its option), and w_z = 1 (eps_{s,F} alone, one UNet call) at the rest. None (or as many as
            the reverse steps): `w_z` at every step. Each guided step costs a base call. The unet and
            classifier heads apply `w_z` at every step.
        failure_guard_steps: Set denoiser: in the last `failure_guard_steps` reverse steps, guide eps_{s,F}
            away from F with its guard, a failure-set classifier trained beside it on the same rows (0: no
            guard; as many as the reverse steps or more: every step, as for `w_z_steps`). Near zero noise
            P(a_0 outside F | a_t) is nearly 0 or 1, so the guard moves only the samples the set denoiser let
            onto a failed option and leaves the proportions of the others. Each guarded step costs one
            classifier forward and backward.
        failure_guard_weight: Set denoiser: the weight of the guard's gradient at its guarded steps (1: the
            classifier-guidance estimate of p(a_t | s) P(a_0 outside F | a_t, s); above 1 pushes harder at
            no extra cost, for what one weight leaves on a failed option).
        history_length: States and actions before the observation window that form the history condition
            h_t^H. 0 trains no history condition.
        recovery_mode: How a plan is drawn after failures: "ccdp" (composition), "dp" (the base alone,
            failures ignored) or "dp_star" (the base's candidates, those whose outcome repeats a failure
            rejected).
        recovery_head: The recovery model: "unet" (eps_z(z), one term per failure, on a synthesised recovery
            dataset), "set_denoiser" (eps_{s,F}: one term for the whole failure set, trained on the base's own
            samples at option starts and along the demonstrations) or "classifier" (a noisy-chunk classifier
            of "repeats a failure", trained on the demonstrations, whose gradient guides eps_s). "auto" (the
            default): "set_denoiser", the head the benchmark measured, where it runs (state inputs and
            n_obs_steps 1), else "unet" (cameras, or n_obs_steps > 1). It is named when the features are known
            (`validate_features`), so a checkpoint's config.json holds the head, never "auto".
        training_stage: What lerobot-train trains: "base" (the diffusion UNet on demonstrations) or "recovery"
            (the recovery head, from a base checkpoint given by --policy.path).
        failure_feature: What z describes: "final_state" (where the option ends), "primitive" (a one-hot label
            from the `primitive_key` dataset column) or "action" (the attempt's first chunk).
        failure_state_dims: final_state: which dims of the state frame form z: `observation.state`'s dims
            first, then `observation.environment_state`'s (index robot_dim + i for its dim i). Empty: every
            dim of `observation.state`.
        failure_state_at: final_state: where a failure's z is read: "demonstrated_end" (the default: where
            the demonstrated chunk nearest the failed one ends, i.e. where the attempt was heading, a z the
            head trained on; needs the outcome table, as `primitive` does, and a planned chunk) or
            "attempt_end" (the state where the failed attempt stopped). The default names a failure as
            `failure_label_at`'s default does a label: by the demonstrated chunk nearest the one executing.
        failure_segments: final_state: where a demonstrated option ends: "labels" (runs of one `primitive_key`
            label, the whole episode without that column), "drops" (the gripper, the action's last dim, lets
            go and the hand opens) or "pauses" (the action holds still for two frames).
        primitive_key: primitive: the dataset column holding the per-frame label.
        failure_label_at: primitive: which label names a failure: "latest_chunk" (that of the demonstrated
            chunk nearest the chunk executing when the failure was flagged) or "attempt_end" (that of the
            demonstrated option whose end, in `failure_state_dims`, is nearest the state
            where the attempt stopped: right where a chunk that finished one option fails the next one).
        num_primitives: primitive: how many labels exist.
        failure_signal_file: A file whose appearance or touch reports a failure of every row, for loops such
            as lerobot-record that pass no failure signal (policy/failure_signal.py). A setting of the machine
            the policy acts on: never saved in a checkpoint.
        z_fourier_octaves: Set denoiser and classifier: each failure's z enters the set embedding as z with
            sin and cos of 2^k pi z for k < z_fourier_octaves (0: z alone), so that a point z (`final_state`)
            whose options lie a few tenths apart in normalised units is told apart as easily as a one-hot
            label. None (the default): by what z is, named with the features (`validate_features`, so
            config.json holds a number): `FOURIER_OCTAVES_OF_A_POINT` for `final_state`, 0 for a one-hot
            `primitive` or an `action` chunk. Part of the head's architecture: set with the base or at the
            recovery stage beside --policy.path.
        delta_z: Squared distance in z under which an outcome repeats a failure (DP*'s rejection, the set
            denoiser's training sets, and eq. (5)'s recovery pairs unless the recipe gives its own).
        stratum_weights: Set denoiser, recovery stage: weigh each kept row by 1 / (1 - p_s(F)), p_s(F) the
            share of the base's chunks at the row's state whose outcome lies in its failure set, so that every
            (state, failure set) counts alike and the rare sets that leave little of the base are learned as
            well as the common ones (`failure_buffer.stratum_weights`). False: every kept row weighs 1.
        state_failure_sets: Set denoiser, recovery stage: the share of the synthesised rows whose training
            failure set is drawn from the outcomes the base reaches from the row's own state (its siblings)
            instead of from other rows (`failure_buffer.draw_state_failure_sets`). Sets drawn from other rows
            seldom hold what the base does at the row's state, so the recoveries that matter (the base's usual
            options there failed) are barely trained; either way the target stays p_s outside F. 0: other
            rows only.
        dp_star_candidates: DP*: candidates drawn per plan.
        dp_star_rounds: DP*: rounds of fresh candidates for a row whose candidates were all rejected, before
            it falls back to the candidate farthest from every failure (1: no redraw).
        row_noise_streams: Each batch row of each rollout draws its noise from its own generator seeded from
            lerobot-eval's --seed, so modes evaluated on the same seed act alike until the first failure
            (common random numbers; about 1% of a plan's time). False: torch's global generator, as
            LeRobot's diffusion policy.
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
    # Vision (same fields and defaults as LeRobot's DiffusionConfig; its RGB encoder is reused as is). The
    # backbone is randomly initialised unless `pretrained_backbone_weights` names torchvision weights (e.g.
    # "ResNet18_Weights.IMAGENET1K_V1"), which torchvision must find in its cache or download.
    vision_backbone: str = "resnet18"
    # ResNet stages kept (4 = LeRobot's encoder). Each stage halves the feature map: 3 keeps a 4x4 map of
    # 64 px images for the spatial softmax (4 stages leave 2x2) at a quarter of the backbone's parameters.
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

    # CCDP (see Args above).
    w_h: float = 0.0
    w_z: float = 5.0
    w_z_steps: int | None = 3
    failure_guard_steps: int = 4
    failure_guard_weight: float = 8.0
    history_length: int = 0
    recovery_mode: RecoveryMode = "ccdp"
    recovery_head: RecoveryHeadSetting = "auto"
    training_stage: TrainingStage = "base"
    failure_feature: FailureFeatureKind = "final_state"
    failure_state_dims: list[int] = field(default_factory=list)
    failure_state_at: FailureStateAt = "demonstrated_end"
    failure_segments: FailureSegments = "labels"
    primitive_key: str = "primitive"
    failure_label_at: FailureLabelAt = "latest_chunk"
    num_primitives: int = 0
    failure_signal_file: str | None = None
    z_fourier_octaves: int | None = None
    delta_z: float = 0.1
    stratum_weights: bool = False
    state_failure_sets: float = 0.0
    dp_star_candidates: int = 32
    dp_star_rounds: int = 4
    row_noise_streams: bool = True

    # Training presets.
    optimizer_lr: float = 1e-3
    optimizer_betas: tuple = (0.95, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-6
    scheduler_name: str = "cosine"
    scheduler_warmup_steps: int = 100

    def __post_init__(self):
        super().__post_init__()
        check_settings(self)

    def _save_pretrained(self, save_directory: Path) -> None:
        """Save without `failure_signal_file`: a path on this machine is no part of the model, and a
        checkpoint someone else loads must not choose a file for their policy to watch."""
        signal, self.failure_signal_file = self.failure_signal_file, None
        try:
            super()._save_pretrained(save_directory)
        finally:
            self.failure_signal_file = signal

    def validate_features(self) -> None:
        """Name the default recovery head for these features (`heads.name_default_head`), check the settings
        again (`CCDPPolicy.__init__` calls this: a config edited after it was made, or passed to
        `from_pretrained(path, config=...)`, gets the same checks as `CCDPConfig()` and the CLI), then the
        dataset/env features against what the policy needs, and declare the z input."""
        from lerobot_ccdp.policy.heads import name_default_head  # the heads import this module

        name_default_head(self)
        self.z_fourier_octaves = z_fourier_octaves_of(self)
        check_settings(self)
        check_features(self)
        if len(self.action_feature.shape) == 2:
            # Recovery datasets store one chunk per frame: (horizon, action_dim). The policy acts per step.
            self.output_features[ACTION] = PolicyFeature(FeatureType.ACTION, self.action_feature.shape[-1:])
        self.input_features[FAILURE_FEATURE_KEY] = PolicyFeature(
            FeatureType.STATE, (self.failure_feature_dim,)
        )

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
        """Size of one observation frame as the networks see it: low-dimensional state, then camera
        features."""
        return self.state_dim + self.image_feature_dim

    @property
    def action_dim(self) -> int:
        return self.action_feature.shape[-1]

    @property
    def failure_feature_dim(self) -> int:
        if self.failure_feature == "final_state":
            return len(self.failure_state_dims) or self.robot_state_feature.shape[0]
        if self.failure_feature == "action":
            return self.horizon * self.action_dim
        return self.num_primitives

    @property
    def trains_on_windows(self) -> bool:
        """Whether this stage reads demonstration windows (the base, and the heads that learn from the demos
        too) rather than whole recovery rows of a synthesised dataset."""
        return self.training_stage == "base" or self.recovery_head_learns_from_demonstrations

    @property
    def recovery_head_learns_from_demonstrations(self) -> bool:
        """Whether the recovery head trains on the demonstrations themselves (no synthesised recovery
        dataset)."""
        from lerobot_ccdp.policy.heads import head_of  # the heads import this module

        return head_of(self).training_data == "demonstrations"

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


def z_fourier_octaves_of(config: CCDPConfig) -> int:
    """`z_fourier_octaves`, or where it is None the default for what z is: a point (`final_state`) gets
    `FOURIER_OCTAVES_OF_A_POINT`, a one-hot label or a whole chunk none."""
    if config.z_fourier_octaves is not None:
        return config.z_fourier_octaves
    return FOURIER_OCTAVES_OF_A_POINT if config.failure_feature == "final_state" else 0
