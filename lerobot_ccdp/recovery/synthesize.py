"""`lerobot-ccdp-synthesize`: turn demonstrations and a base checkpoint into a recovery dataset
(paper eq. 5-7).

It builds a pool of chunks with their states and failure features z: `n_states` demo states x_s, perturbed
(x = x_s + xi, xi ~ N(0, sigma^2), eq. 6), with `chunks_per_state` chunks sampled at each from the base
composition of eq. (7), plus up to `demo_frames` demonstrated chunks ("pairs straight from the demos"). z of
every chunk comes from the policy's own `FailureFeature`; a sampled chunk borrows the outcome of its nearest
demonstrated chunk, so with `outcome_radius` > 0 sampled chunks farther than that from every demonstrated
chunk (RMS per action element) are dropped: no demonstration says what they lead to. Every pool sample then
serves as a failure (a_f, x_f), and up to `pairs_per_failure` recoveries are drawn among the pool samples that
satisfy eq. (5) against it. Every row holds one pair:

    action                       the recovery chunk a (horizon, action_dim), raw units
    observation.failure_feature  z of the failed chunk, raw units (stats from `failure_feature_stats`)
    failure_action               the failed chunk a_f, kept for inspection
    observation.state / .environment_state   the state of the recovery chunk (last frame of its window)
    pair_source                  where the recovery chunk comes from: 0 synthesised, 1 demonstrated

A set-denoiser dataset (`recovery_head=set_denoiser`) holds the base's own samples, each its own row, and
beside each the outcomes of every chunk sampled at its state (`observation.failure_feature_siblings`,
normalised z, with `..._sibling_count`), from which the recovery stage may weigh its rows (`stratum_weights`).

The dataset carries the checkpoint's normalisation stats (lerobot-train normalises with the training
dataset's stats, so recovery training sees actions exactly as the base did) and a copy of the recipe with
the source dataset and checkpoint in `meta/ccdp_recovery_recipe.yaml`. It is written atomically.

On a camera dataset, eq. (6) perturbs the low-dimensional state only and keeps the frame's recorded images,
which the base encodes into the state condition of eq. (7); eq. (5)'s state distance is over the
low-dimensional state. The recovery stage reads only z and chunks, so no image is copied into the recovery
dataset; it carries the cameras' normalisation stats, which the recovery checkpoint's preprocessor needs.

    lerobot-ccdp-synthesize --policy.path=<base run>/checkpoints/last/pretrained_model \
        --dataset.repo_id=local/door_opening --dataset.root=data/door_opening \
        --output.root=data/door_opening_recovery
        [--config_path=datasets_recipes/door_opening.yaml] [--recovery.sigma=0.05]

Without a recipe file z is the checkpoint's (`RecoveryRecipe.for_checkpoint`) and the rows are written as
local/<output folder>.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import yaml
from lerobot.configs import parser
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.datasets.utils import dataset_to_policy_features, write_stats
from lerobot.processor import NormalizerProcessorStep, PolicyProcessorPipeline
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE
from lerobot.utils.utils import is_torch_device_available
from torch import Tensor
from tqdm import tqdm

from lerobot_ccdp.compat.episode_writes import image_free_episodes
from lerobot_ccdp.datasets.camera_windows import CameraWindows
from lerobot_ccdp.datasets.configs import SynthesizeConfig, parse_cli
from lerobot_ccdp.datasets.recipe_file import RecoveryRecipe
from lerobot_ccdp.datasets.staging import check_disjoint, check_output_root, staged_dataset_root
from lerobot_ccdp.policy.checkpoint_files import checkpoint_loading
from lerobot_ccdp.policy.configuration_ccdp import (
    FAILURE_FEATURE_KEY,
    SIBLING_COUNT_KEY,
    SIBLING_FEATURES_KEY,
    CCDPConfig,
)
from lerobot_ccdp.policy.demo_segments import segment_ends
from lerobot_ccdp.policy.failure_features import failure_feature_stats
from lerobot_ccdp.policy.heads import head_class
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.policy.outcome_index import demo_chunks
from lerobot_ccdp.policy.outcome_table import read_columns
from lerobot_ccdp.policy.processor_ccdp import normalize_batch, unnormalize_batch
from lerobot_ccdp.recovery.recovery_pairs import pick_pairs, recovery_pair_mask

logger = logging.getLogger(__name__)

FAILURE_ACTION = "failure_action"
PAIR_SOURCE = "pair_source"
RECIPE_COPY = "meta/ccdp_recovery_recipe.yaml"
SYNTHESISED, FROM_DEMOS = 0, 1
PAIR_BLOCK = 256  # failures whose eq. (5) masks against the whole pool are computed at once
# rows per dataset episode (recovery rows have no temporal order; episodes only group them)
EPISODE_ROWS = 1000


@dataclass
class Samples:
    """Chunks with the state they were taken in and their failure feature, in the policy's normalised
    space."""

    windows: Tensor  # (R, n_obs_steps, state_dim): the observation window the chunk starts from
    chunks: Tensor  # (R, horizon, A)
    z: Tensor  # (R, z_dim)
    source: Tensor  # (R,): SYNTHESISED or FROM_DEMOS
    state_id: Tensor  # (R,): which drawn demo state a synthesised chunk was sampled at; -1 for a demo chunk
    frame: Tensor  # (R,): the demo frame whose window the chunk starts from (perturbed if synthesised)

    @staticmethod
    def cat(parts: list[Samples]) -> Samples:
        return Samples(
            *(torch.cat([getattr(p, name) for p in parts]) for name in Samples.__dataclass_fields__)
        )

    def __len__(self) -> int:
        return self.chunks.shape[0]


@dataclass
class Demos:
    """The demo dataset in the policy's normalised space."""

    windows: Tensor  # (N, n_obs_steps, state_dim): the observation window ending at each frame
    chunks: Tensor  # (N, horizon, A): the chunk each frame starts (as in training)
    starts: Tensor  # the first frame of each demonstrated option, where an attempt starts (`option_starts`)


def synthesis_device(saved: str | None, requested: str | None) -> str:
    """`requested` (--policy.device) if this machine has it; else the checkpoint's saved device, or the CPU
    where that one is absent (a base trained on a GPU is synthesised from on any machine)."""
    if requested is None:
        return saved if saved and is_torch_device_available(saved) else "cpu"
    try:
        available = is_torch_device_available(requested)
    except ValueError:
        available = False
    if not available:
        raise ValueError(
            f"--policy.device={requested} is not available on this machine. Pass --policy.device=cpu (or "
            "cuda, mps where present), or leave it out to follow the checkpoint's device."
        )
    return requested


def check_demo_root(root: str | Path) -> None:
    """The demos must be a local dataset: named here, a wrong --dataset.root is not mistaken for a Hub
    download."""
    root = Path(root)
    if not (root / "meta" / "info.json").is_file():
        problem = "the folder does not exist" if not root.exists() else "it has no meta/info.json"
        raise FileNotFoundError(
            f"No LeRobot dataset at --dataset.root={root}: {problem}. Record the demos there first "
            "(lerobot-ccdp-record) or fix the path."
        )


def load_checkpoint(
    policy_path: str | Path, device: str | None = None
) -> tuple[CCDPPolicy, dict[str, dict[str, Tensor]]]:
    """The base policy on the device `synthesis_device` picks, and the normalisation stats of its saved
    preprocessor."""
    # names a missing or damaged folder; refuses unknown processor classes
    with checkpoint_loading(policy_path):
        config = PreTrainedConfig.from_pretrained(policy_path)
    if not isinstance(config, CCDPConfig):
        raise ValueError(
            f"{policy_path} holds a {config.type!r} policy; synthesis needs a ccdp base checkpoint "
            "(lerobot-train --policy.type=ccdp on the demo dataset)."
        )
    config.device = synthesis_device(config.device, device)
    policy = CCDPPolicy.from_pretrained(policy_path, config=config).eval()
    # The saved preprocessor names the training device, which this machine may lack (LeRobot's scripts
    # override it too).
    pre = PolicyProcessorPipeline.from_pretrained(
        policy_path,
        config_filename="policy_preprocessor.json",
        overrides={"device_processor": {"device": config.device}},
    )
    normalizers = [s for s in pre.steps if isinstance(s, NormalizerProcessorStep)]
    if not normalizers or not normalizers[0].stats:
        raise ValueError(
            f"{policy_path} has no normaliser stats in policy_preprocessor.json; save the checkpoint "
            "with its processors (lerobot-train does)."
        )
    stats = {k: {s: torch.as_tensor(v) for s, v in d.items()} for k, d in normalizers[0].stats.items()}
    return policy, stats


def check_features_match(config: CCDPConfig, meta: LeRobotDatasetMetadata) -> None:
    """The checkpoint must be trained on data of the demos' layout, or sampling fails on a tensor size."""
    keys = [OBS_STATE, *([OBS_ENV_STATE] if config.env_state_feature else []), *config.image_features, ACTION]
    expected = {**config.input_features, **config.output_features}
    found = dataset_to_policy_features(meta.features)

    def layout(features: dict) -> str:
        return ", ".join(f"{k} {tuple(features[k].shape) if k in features else 'absent'}" for k in keys)

    if layout(expected) != layout(found):
        raise ValueError(
            f"The base checkpoint expects {layout(expected)}; dataset {meta.repo_id} has "
            f"{layout(found)}. Pass the checkpoint trained on these demos (--policy.path), or "
            "the demos it was trained on (--dataset.root)."
        )


def load_demos(config: CCDPConfig, stats: dict, meta: LeRobotDatasetMetadata) -> Demos:
    """Read and normalise the demo columns the policy and the recipe need; name any that are missing."""
    keys = [OBS_STATE] + ([OBS_ENV_STATE] if config.env_state_feature else [])
    required = [*keys, ACTION]
    if config.failure_feature == "primitive":
        required.append(config.primitive_key)
    columns = read_columns(meta, required, optional=[config.primitive_key])
    normalized = normalize_batch(config, stats, {k: torch.from_numpy(columns[k]) for k in [*keys, ACTION]})
    frames = torch.cat([normalized[k] for k in keys], dim=-1).numpy()
    episodes = columns["episode_index"]
    start = 1 - config.n_obs_steps
    return Demos(
        windows=torch.from_numpy(demo_chunks(episodes, frames, start, config.n_obs_steps)),
        chunks=torch.from_numpy(demo_chunks(episodes, normalized[ACTION].numpy(), start, config.horizon)),
        starts=torch.from_numpy(
            option_starts(config, episodes, normalized[ACTION].numpy(), columns.get(config.primitive_key))
        ),
    )


def option_starts(
    config: CCDPConfig, episodes: np.ndarray, actions: np.ndarray, labels: np.ndarray | None
) -> np.ndarray:
    """The first frame of every demonstrated option: each episode's first frame and the frame after each end
    of an option (`demo_segments.segment_ends` under `failure_segments`, the rule that gives z its final
    state). An attempt starts at such a state, and after a failure the env puts the robot back there: on tasks
    with two decisions per episode (packing, the Bartender) the second decision's start is one too."""
    ends = segment_ends(config.failure_segments, episodes.reshape(-1), actions, labels)
    return np.flatnonzero(np.r_[True, ends[:-1]])


def set_denoiser_frames(demos: Demos) -> Tensor:
    """The demo frames the set denoiser's states are drawn among: half at option starts, half along every
    demonstrated frame (the starts repeated to match the frames' count). F decides the option at its start;
    but a pick and place spans several plans, each composed with F, so the head must also have seen the states
    along an attempt. With starts only, packing's attempts after a failure stalled mid-way (CCDP 0.45 against
    DP* 0.71 on the development seeds); with both, 0.70 (docs/benchmarks.md)."""
    frames = torch.arange(len(demos.chunks))
    return torch.cat([demos.starts.repeat(max(1, len(frames) // len(demos.starts))), frames])


def synthesised_samples(
    policy: CCDPPolicy,
    recipe: RecoveryRecipe,
    demos: Demos,
    generator: torch.Generator,
    progress: bool = True,
    images: Callable[[Tensor], Tensor] | None = None,
    among: Tensor | None = None,
) -> Samples:
    """Eq. (6) and (7): demo states x_s perturbed by N(0, sigma^2), `chunks_per_state` chunks sampled at each.

    The states are drawn among every demo frame, or among the frames `among` names. `images` maps demo frame
    indices to their encoded camera windows (b, n_obs, F), for checkpoints with cameras. Random draws come
    from `generator` on the CPU, so a seed gives the same inputs on every device.
    """
    cfg, k, device = policy.config, recipe.chunks_per_state, torch.device(policy.config.device)
    among = torch.arange(len(demos.windows)) if among is None else among
    picks = among[torch.randint(0, len(among), (recipe.n_states,), generator=generator)]
    parts = []
    drawn = torch.arange(recipe.n_states).split(recipe.batch_states)
    for ids in tqdm(drawn, desc="Sampling chunks (eq. 7)", disable=not progress):
        batch, state_id = picks[ids], ids.repeat_interleave(k)
        frame = batch.repeat_interleave(k)
        x_s = demos.windows[batch].repeat_interleave(k, dim=0)  # (b * k, n_obs, D)
        x = x_s + recipe.sigma * torch.randn(x_s.shape, generator=generator)  # eq. (6)
        condition = x if images is None else torch.cat([x, images(batch).repeat_interleave(k, dim=0)], dim=-1)
        noise = torch.randn(len(x), cfg.horizon, cfg.action_dim, generator=generator)
        condition, noise = condition.flatten(start_dim=1).to(device), noise.to(device)
        # eq. (7), on the policy's device
        chunks = policy.model.sample_exploratory(condition, recipe.w_s, noise)
        if recipe.outcome_radius:  # before z: a dropped chunk's borrowed outcome is never needed
            near = policy.model.outcomes.rms_distance(chunks) <= recipe.outcome_radius
            x, chunks, state_id, frame = x[near.cpu()], chunks[near], state_id[near.cpu()], frame[near.cpu()]
        z = policy.model.feature.from_chunk(chunks, policy.model.outcomes)
        parts.append(Samples(x, chunks.cpu(), z.cpu(), torch.full((len(x),), SYNTHESISED), state_id, frame))
    return Samples.cat(parts)


def camera_encoder(
    policy: CCDPPolicy, stats: dict, meta: LeRobotDatasetMetadata
) -> Callable[[Tensor], Tensor]:
    """Demo frame indices -> the base's encoding of their camera windows (b, n_obs, F), as at run time."""
    cameras = list(policy.config.image_features)
    windows = CameraWindows(meta, cameras, policy.config.n_obs_steps)

    def encode(frames: Tensor) -> Tensor:
        images = normalize_batch(policy.config, stats, windows(frames))
        with torch.no_grad():
            return policy.model.images([images[key].to(policy.config.device) for key in cameras]).cpu()

    return encode


def demo_samples(
    policy: CCDPPolicy,
    recipe: RecoveryRecipe,
    demos: Demos,
    generator: torch.Generator,
    among: Tensor | None = None,
) -> Samples:
    """Up to `demo_frames` demonstrated chunks (among the frames `among` names, if given), with their z
    computed like any other chunk's."""
    among = torch.arange(len(demos.windows)) if among is None else among
    pick = among[torch.randperm(len(among), generator=generator)[: recipe.demo_frames]]
    chunks = demos.chunks[pick]
    z = policy.model.feature.from_chunk(chunks.to(policy.config.device), policy.model.outcomes).cpu()
    return Samples(
        demos.windows[pick],
        chunks,
        z,
        torch.full((len(pick),), FROM_DEMOS),
        torch.full((len(pick),), -1),
        pick,
    )


def recovery_pairs(
    pool: Samples, recipe: RecoveryRecipe, generator: torch.Generator
) -> tuple[Tensor, Tensor]:
    """Eq. (5) over the whole pool: every sample is a failure (a_f, x_f); up to `pairs_per_failure` recoveries
    are drawn uniformly among the pool samples that satisfy eq. (5) against it. Returns (failure, recovery)
    indices."""
    states = pool.windows.flatten(start_dim=1)
    failures, recoveries = [], []
    for block in torch.arange(len(pool)).split(PAIR_BLOCK):
        mask = recovery_pair_mask(
            pool.z[block], states[block], pool.z, states, recipe.delta_z, recipe.delta_x
        )
        row, _, j = pick_pairs(mask[:, None], recipe.pairs_per_failure, generator)
        failures.append(block[row])
        recoveries.append(j)
    return torch.cat(failures), torch.cat(recoveries)


def own_outcome_rows(pool: Samples) -> tuple[Tensor, Tensor]:
    """For `recovery_head=set_denoiser`: every pool sample is a row of its own (its z is its own outcome),
    with no pairing. Drawn at option starts and along the demonstrations (`set_denoiser_frames`), at w_s = 1
    they are the base's own plans there, which the set denoiser learns to restrict to the options outside a
    failure set; the same (failure, recovery) indices as `recovery_pairs`."""
    rows = torch.arange(len(pool))
    return rows, rows


def sibling_outcomes(
    pool: Samples, chunks_per_state: int, demo_siblings: bool = False
) -> tuple[Tensor, Tensor]:
    """For `recovery_head=set_denoiser`: each pool sample's siblings, the outcomes z of every chunk sampled at
    the same drawn state (itself included), (R, chunks_per_state, z_dim) zero-padded, and how many are real
    (R,). They estimate the base's share of each failure set at that state (`failure_buffer.stratum_weights`).
    A demonstrated chunk has none, or with `demo_siblings` those of the first state drawn at its frame (if one
    was): the base's draws where the demonstrator chose that chunk, so that its failure sets and weight are
    those of the synthesised rows there. A recovery the base almost never samples (home with the two nearest
    cups failed) is then trained on the demonstrations of it at that stratum's weight, not at weight 1 under
    failure sets drawn from other states."""
    synthesised = pool.state_id >= 0
    ids = pool.state_id[synthesised]
    table = torch.zeros(int(ids.max()) + 1 if len(ids) else 0, chunks_per_state, pool.z.shape[1])
    count = torch.bincount(ids, minlength=len(table))
    first = torch.cumsum(count, dim=0) - count  # pool samples of one state are contiguous, in drawing order
    table[ids, torch.arange(len(ids)) - first[ids]] = pool.z[synthesised]
    siblings = torch.zeros(len(pool), chunks_per_state, pool.z.shape[1])
    counts = torch.zeros(len(pool), dtype=torch.long)
    siblings[synthesised], counts[synthesised] = table[ids], count[ids]
    if demo_siblings and len(ids):
        none = len(table)
        state_at = torch.full((int(pool.frame.max()) + 1,), none)  # the first state drawn at each frame
        state_at = state_at.scatter_reduce(0, pool.frame[synthesised], ids, reduce="amin")
        demo = torch.nonzero(~synthesised).flatten()
        state = state_at[pool.frame[demo]]
        drawn = state < none
        siblings[demo[drawn]], counts[demo[drawn]] = table[state[drawn]], count[state[drawn]]
    return siblings, counts


def synthesize_recovery_dataset(
    recipe: RecoveryRecipe,
    demo_repo_id: str,
    demo_root: str | Path,
    policy_path: str | Path,
    out_repo_id: str,
    out_root: str | Path,
    *,
    overwrite: bool = False,
    progress: bool = True,
    recipe_source: str = "recipe",
    device: str | None = None,
    recovery_head: str | None = None,
) -> Path:
    """Write the recovery dataset of `recipe` at `out_root` (atomically) and return `out_root`. The pool and
    the dataset are built on the CPU; the policy's networks run on `device` (see `synthesis_device`). The rows
    are those `recovery_head` trains on (None: the checkpoint's head), so that another head of the same base
    (lerobot-train's --policy.recovery_head at the recovery stage) gets its own."""
    started = time.perf_counter()
    if recovery_head:  # None or empty: the checkpoint's head, checked when it loads
        head_class(recovery_head)  # a wrong name, before minutes of loading and sampling
    # Before minutes of loading and sampling, not after.
    inputs = {"--dataset.root": demo_root}
    if Path(policy_path).is_dir():  # a local checkpoint folder, not a Hub repo id
        inputs["--policy.path"] = policy_path
    check_disjoint(out_root, inputs)
    check_output_root(out_root, overwrite)
    check_demo_root(demo_root)
    policy, stats = load_checkpoint(policy_path, device)
    config = policy.config
    recipe = recipe.for_checkpoint(config, recipe_source)  # z as the base was trained with
    head = head_class(recovery_head or config.recovery_head)
    if recipe.demo_siblings and head.training_data != "base_samples":
        raise ValueError(
            f"recovery.demo_siblings gives demonstrated rows the siblings that only the set denoiser's rows "
            f"carry, and the rows are for recovery_head={head.name!r}: pass --recovery.demo_siblings=false, "
            "or write the set denoiser's rows (--policy.recovery_head=set_denoiser)."
        )
    if config.failure_feature != "action" and len(policy.model.outcomes) == 0:
        raise ValueError(
            f"{policy_path} holds no demonstrated outcomes, so z of a sampled chunk is unknown; "
            "train the base stage from the demo dataset with lerobot-train."
        )
    meta = LeRobotDatasetMetadata(demo_repo_id, root=demo_root)
    check_features_match(config, meta)
    demos = load_demos(config, stats, meta)
    generator = torch.Generator().manual_seed(recipe.seed)
    torch.manual_seed(recipe.seed)
    sampling_started = time.perf_counter()
    images = camera_encoder(policy, stats, meta) if config.image_features else None
    # The set denoiser learns from the chunks along its attempts (`set_denoiser_frames`, `own_outcome_rows`);
    # eq. (4)'s eps_z from pairs.
    among = set_denoiser_frames(demos) if head.training_data == "base_samples" else None
    parts = (
        [synthesised_samples(policy, recipe, demos, generator, progress, images, among)]
        if recipe.n_states
        else []
    )
    sampling_seconds = time.perf_counter() - sampling_started
    if recipe.demo_frames:
        parts.append(demo_samples(policy, recipe, demos, generator, among))
    pool = Samples.cat(parts)
    if recipe.n_states and recipe.outcome_radius and not (pool.source == SYNTHESISED).any():
        raise ValueError(
            f"Every sampled chunk lies farther than outcome_radius={recipe.outcome_radius} from the "
            "demonstrated chunks, so none has an outcome to borrow. Raise outcome_radius (0 keeps all) "
            "or train the base checkpoint longer."
        )
    failure, recovery = (
        own_outcome_rows(pool) if among is not None else recovery_pairs(pool, recipe, generator)
    )
    siblings = (
        sibling_outcomes(pool, recipe.chunks_per_state, recipe.demo_siblings) if among is not None else None
    )
    if len(failure) == 0:
        raise ValueError(
            f"No pair satisfies eq. (5) with delta_z={recipe.delta_z}, delta_x={recipe.delta_x}: the "
            "sampled chunks never differ in z at nearby states. Lower delta_z, raise delta_x, sigma or "
            "chunks_per_state, or lower w_s to widen the proposals."
        )
    stats = {
        **stats,
        FAILURE_FEATURE_KEY: {k: torch.as_tensor(v) for k, v in failure_feature_stats(config, stats).items()},
    }
    result = {
        "rows": len(failure),
        "sampled": recipe.n_states * recipe.chunks_per_state,
        "pool_synthesised": int((pool.source == SYNTHESISED).sum()),
        "pool_demo": int((pool.source == FROM_DEMOS).sum()),
        "recoveries_synthesised": int((pool.source[recovery] == SYNTHESISED).sum()),
        "recoveries_from_demos": int((pool.source[recovery] == FROM_DEMOS).sum()),
        "sampling_seconds": round(sampling_seconds, 2),
    }
    if siblings is not None:
        result["demo_with_siblings"] = int(((pool.source == FROM_DEMOS) & (siblings[1] > 0)).sum())
    with staged_dataset_root(out_root, overwrite) as path:
        _write(path, out_repo_id, config, stats, pool, failure, recovery, meta, siblings)
        result["seconds"] = round(time.perf_counter() - started, 2)
        record = {
            "recovery": asdict(recipe),
            "source": {"repo_id": demo_repo_id, "root": str(demo_root), "policy_path": str(policy_path)},
            "recovery_head": head.name,
            "result": result,
        }
        (path / RECIPE_COPY).write_text(yaml.safe_dump(record, sort_keys=False))
    logger.info(
        "Wrote %d recovery pairs from a pool of %d synthesised and %d demonstrated chunks to %s in %.1f s",
        result["rows"],
        result["pool_synthesised"],
        result["pool_demo"],
        out_root,
        result["seconds"],
    )
    return Path(out_root)


def _write(
    path: Path,
    repo_id: str,
    config: CCDPConfig,
    stats: dict,
    pool: Samples,
    failure: Tensor,
    recovery: Tensor,
    meta: LeRobotDatasetMetadata,
    siblings: tuple[Tensor, Tensor] | None = None,
) -> None:
    """One dataset row per (failure, recovery) pair, in raw units, with the checkpoint's stats; and the
    recovery chunk's sibling outcomes (`sibling_outcomes`, the policy's normalised z) when given."""
    keys = [OBS_STATE] + ([OBS_ENV_STATE] if config.env_state_feature else [])
    sizes = [config.input_features[k].shape[0] for k in keys]
    raw = unnormalize_batch(
        config,
        stats,
        {
            **dict(zip(keys, pool.windows[recovery, -1].split(sizes, dim=-1), strict=True)),
            FAILURE_FEATURE_KEY: pool.z[failure],
            ACTION: pool.chunks[recovery],
        },
    )
    raw[FAILURE_ACTION] = unnormalize_batch(config, stats, {ACTION: pool.chunks[failure]})[ACTION]
    raw[PAIR_SOURCE] = pool.source[recovery][:, None]
    chunk_spec = {"dtype": "float32", "shape": tuple(pool.chunks.shape[1:]), "names": None}
    features = {
        **{k: meta.features[k] for k in keys},
        ACTION: chunk_spec,
        FAILURE_ACTION: chunk_spec,
        FAILURE_FEATURE_KEY: {"dtype": "float32", "shape": (config.failure_feature_dim,), "names": None},
        PAIR_SOURCE: {"dtype": "int64", "shape": (1,), "names": None},
    }
    if siblings is not None:
        raw[SIBLING_FEATURES_KEY], raw[SIBLING_COUNT_KEY] = siblings[0][recovery], siblings[1][recovery, None]
        shape = tuple(siblings[0].shape[1:])
        features[SIBLING_FEATURES_KEY] = {"dtype": "float32", "shape": shape, "names": None}
        features[SIBLING_COUNT_KEY] = {"dtype": "int64", "shape": (1,), "names": None}
    integer = (PAIR_SOURCE, SIBLING_COUNT_KEY)
    columns = {k: raw[k].numpy().astype(np.int64 if k in integer else np.float32) for k in features}
    task = f"recover from a failure: {meta.tasks.index[0]}" if len(meta.tasks) else "recover from a failure"
    dataset = LeRobotDataset.create(repo_id, fps=meta.fps, features=features, root=path, use_videos=False)
    try:
        with image_free_episodes():
            for start in range(0, len(failure), EPISODE_ROWS):
                for row in range(start, min(start + EPISODE_ROWS, len(failure))):
                    dataset.add_frame({**{k: v[row] for k, v in columns.items()}, "task": task})
                dataset.save_episode()
    finally:
        dataset.finalize()
    # The chunk columns' per-frame stats are meaningless for the normaliser: use the checkpoint's, per action
    # dim.
    written = {**dataset.meta.stats}
    for key in [*keys, *config.image_features, ACTION, FAILURE_FEATURE_KEY]:
        written[key] = {k: v.numpy() for k, v in stats[key].items()}
    written[FAILURE_ACTION] = written[ACTION]
    write_stats(written, path)


def main(args: list[str] | None = None) -> None:
    """`lerobot-ccdp-synthesize --config_path=<recipe yaml> --dataset.* --policy.path=... --output.*` (see
    --help)."""
    cfg = parse_cli(SynthesizeConfig, args)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    source = parser.parse_arg("config_path", args) or "given by --recovery.* flags"
    synthesize_recovery_dataset(
        cfg.recovery,
        cfg.dataset.repo_id,
        cfg.dataset.root,
        cfg.policy.path,
        cfg.output.repo_id,
        cfg.output.root,
        overwrite=cfg.overwrite,
        recipe_source=source,
        device=cfg.policy.device,
        recovery_head=cfg.policy.recovery_head,
    )


if __name__ == "__main__":
    main()
