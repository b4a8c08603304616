"""`lerobot-ccdp-synthesize`: turn demonstrations and a base checkpoint into a recovery dataset (paper eq. 5-7).

For `n_states` demo states x_s it perturbs the state (x = x_s + xi, xi ~ N(0, sigma^2), eq. 6), samples
`chunks_per_state` chunks from the base composition of eq. (7), computes z of every chunk with the policy's own
`FailureFeature`, and keeps the pairs (failure i, recovery j) of eq. (5). Pairs drawn straight from the demos
(two demonstrated chunks at nearby states with different z) are added. Every row holds one pair:

    action                       the recovery chunk a_j (horizon, action_dim), raw units
    observation.failure_feature  z of the failed chunk, raw units (stats from `failure_feature_stats`)
    failure_action               the failed chunk a_i, kept for inspection
    observation.state / .environment_state   the state of the recovery chunk (last frame of its window)
    pair_source                  0 synthesised, 1 drawn from the demos

The dataset carries the checkpoint's normalisation stats (lerobot-train normalises with the training
dataset's stats, so recovery training sees actions exactly as the base did) and a copy of the recipe with
the source dataset and checkpoint in `meta/ccdp_recovery_recipe.yaml`. It is written atomically.
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import yaml
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.datasets.utils import write_stats
from lerobot.processor import NormalizerProcessorStep, PolicyProcessorPipeline
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE
from torch import Tensor
from tqdm import tqdm

from lerobot_ccdp.configuration_ccdp import FAILURE_FEATURE_KEY, CCDPConfig
from lerobot_ccdp.failure_features import failure_feature_stats
from lerobot_ccdp.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.outcome_index import demo_chunks
from lerobot_ccdp.outcome_table import read_columns
from lerobot_ccdp.processor_ccdp import normalize_batch, unnormalize_batch
from lerobot_ccdp.recipes.recipe_file import RecoveryRecipe
from lerobot_ccdp.recipes.staging import staged_dataset_root
from lerobot_ccdp.recovery_pairs import pick_pairs, recovery_pair_mask

logger = logging.getLogger(__name__)

FAILURE_ACTION = "failure_action"
PAIR_SOURCE = "pair_source"
RECIPE_COPY = "meta/ccdp_recovery_recipe.yaml"
SYNTHESISED, FROM_DEMOS = 0, 1
DEMO_PAIR_POOL = 4096  # demo frames searched for demo pairs (the search is quadratic in it)
EPISODE_ROWS = 1000  # rows per dataset episode (recovery rows have no temporal order; episodes only group them)


@dataclass
class Pairs:
    """(failure, recovery) pairs in the policy's normalised space."""

    frames: Tensor  # (R, state_dim): state of the recovery chunk (last frame of its window)
    actions: Tensor  # (R, horizon, A): recovery chunk
    z_fail: Tensor  # (R, z_dim)
    failure_actions: Tensor  # (R, horizon, A)
    source: Tensor  # (R,)

    @staticmethod
    def cat(parts: list[Pairs]) -> Pairs:
        return Pairs(*(torch.cat([getattr(p, name) for p in parts]) for name in Pairs.__dataclass_fields__))

    def __len__(self) -> int:
        return self.actions.shape[0]


@dataclass
class Demos:
    """The demo dataset in the policy's normalised space."""

    windows: Tensor  # (N, n_obs_steps, state_dim): the observation window ending at each frame
    chunks: Tensor  # (N, horizon, A): the chunk each frame starts (as in training)


def load_checkpoint(policy_path: str | Path) -> tuple[CCDPPolicy, dict[str, dict[str, Tensor]]]:
    """The base policy and the normalisation stats of its saved preprocessor."""
    policy = CCDPPolicy.from_pretrained(policy_path).eval()
    pre = PolicyProcessorPipeline.from_pretrained(policy_path, config_filename="policy_preprocessor.json")
    normalizers = [s for s in pre.steps if isinstance(s, NormalizerProcessorStep)]
    if not normalizers or not normalizers[0].stats:
        raise ValueError(f"{policy_path} has no normaliser stats in policy_preprocessor.json; save the checkpoint "
                         "with its processors (lerobot-train does).")
    stats = {k: {s: torch.as_tensor(v) for s, v in d.items()} for k, d in normalizers[0].stats.items()}
    return policy, stats


def check_recipe_matches(recipe: RecoveryRecipe, config: CCDPConfig, source: str) -> None:
    """z is defined by the failure settings: the recipe and the checkpoint must agree on them."""
    wanted = recipe.failure_settings()
    mismatched = {k: (v, getattr(config, k)) for k, v in wanted.items() if getattr(config, k) != v}
    if mismatched:
        details = ", ".join(f"{k}: recipe {v!r} vs checkpoint {c!r}" for k, (v, c) in mismatched.items())
        flags = " ".join(f"--policy.{k}={v}" for k, v in wanted.items())
        raise ValueError(f"The recipe {source} and the base checkpoint define z differently ({details}). Train the "
                         f"base with `{flags}`, or edit the recipe's `recovery:` section to match the checkpoint.")


def load_demos(config: CCDPConfig, stats: dict, meta: LeRobotDatasetMetadata) -> Demos:
    """Read and normalise the demo columns the policy and the recipe need; name any that are missing."""
    keys = [OBS_STATE] + ([OBS_ENV_STATE] if config.env_state_feature else [])
    required = [*keys, ACTION, config.failure_state_key]
    if config.failure_feature == "primitive":
        required.append(config.primitive_key)
    columns = read_columns(meta, required)
    normalized = normalize_batch(config, stats, {k: torch.from_numpy(columns[k]) for k in [*keys, ACTION]})
    frames = torch.cat([normalized[k] for k in keys], dim=-1).numpy()
    episodes = columns["episode_index"]
    start = 1 - config.n_obs_steps
    return Demos(
        windows=torch.from_numpy(demo_chunks(episodes, frames, start, config.n_obs_steps)),
        chunks=torch.from_numpy(demo_chunks(episodes, normalized[ACTION].numpy(), start, config.horizon)),
    )


def synthesised_pairs(
    policy: CCDPPolicy, recipe: RecoveryRecipe, demos: Demos, generator: torch.Generator, progress: bool = True
) -> Pairs:
    """Eq. (6) and (7): perturbed demo states, chunks sampled around each, and the pairs of eq. (5) among them."""
    cfg, k = policy.config, recipe.chunks_per_state
    picks = torch.randint(0, len(demos.windows), (recipe.n_states,), generator=generator)
    parts = []
    for batch in tqdm(picks.split(recipe.batch_states), desc="Synthesising recovery pairs", disable=not progress):
        b = len(batch)
        x_s = demos.windows[batch]  # (b, n_obs, D)
        x = x_s[:, None] + recipe.sigma * torch.randn(b, k, *x_s.shape[1:], generator=generator)  # eq. (6)
        noise = torch.randn(b * k, cfg.horizon, cfg.action_dim, generator=generator)
        chunks = policy.sample_exploratory(x.flatten(start_dim=2).flatten(end_dim=1), recipe.w_s, noise)  # eq. (7)
        z = policy.feature.from_chunk(chunks, policy.outcomes).view(b, k, -1)
        chunks, states = chunks.view(b, k, *chunks.shape[1:]), x.flatten(start_dim=2)
        mask = recovery_pair_mask(z, states, z, states, recipe.delta_z, recipe.delta_x)  # eq. (5), (b, k, k)
        group, i, j = pick_pairs(mask, recipe.pairs_per_state, generator)
        parts.append(Pairs(x[group, j, -1], chunks[group, j], z[group, i], chunks[group, i],
                           torch.full((len(group),), SYNTHESISED)))
    return Pairs.cat(parts)


def demo_pairs(policy: CCDPPolicy, recipe: RecoveryRecipe, demos: Demos, generator: torch.Generator) -> Pairs:
    """Pairs of eq. (5) between demonstrated chunks: different outcomes started from nearby states."""
    pool = torch.randperm(len(demos.windows), generator=generator)[:DEMO_PAIR_POOL]
    chunks, windows = demos.chunks[pool], demos.windows[pool]
    z = policy.feature.from_chunk(chunks, policy.outcomes)
    states = windows.flatten(start_dim=1)
    mask = recovery_pair_mask(z, states, z, states, recipe.delta_z, recipe.delta_x)
    _, i, j = pick_pairs(mask[None], recipe.demo_pairs, generator)
    return Pairs(windows[j, -1], chunks[j], z[i], chunks[i], torch.full((len(j),), FROM_DEMOS))


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
) -> Path:
    """Write the recovery dataset of `recipe` at `out_root` (atomically) and return `out_root`."""
    started = time.perf_counter()
    policy, stats = load_checkpoint(policy_path)
    config = policy.config
    check_recipe_matches(recipe, config, recipe_source)
    if config.failure_feature != "action" and len(policy.outcomes) == 0:
        raise ValueError(f"{policy_path} holds no demonstrated outcomes, so z of a sampled chunk is unknown; "
                         "train the base stage from the demo dataset with lerobot-train.")
    meta = LeRobotDatasetMetadata(demo_repo_id, root=demo_root)
    demos = load_demos(config, stats, meta)
    generator = torch.Generator().manual_seed(recipe.seed)
    torch.manual_seed(recipe.seed)
    pairs = [synthesised_pairs(policy, recipe, demos, generator, progress)]
    if recipe.demo_pairs:
        pairs.append(demo_pairs(policy, recipe, demos, generator))
    pairs = Pairs.cat(pairs)
    if len(pairs) == 0:
        raise ValueError(f"No pair satisfies eq. (5) with delta_z={recipe.delta_z}, delta_x={recipe.delta_x}: the "
                         "sampled chunks never differ in z at nearby states. Lower delta_z, raise delta_x, sigma or "
                         "chunks_per_state, or lower w_s to widen the proposals.")
    stats = {**stats, FAILURE_FEATURE_KEY: {k: torch.as_tensor(v) for k, v in failure_feature_stats(config, stats).items()}}
    with staged_dataset_root(out_root, overwrite) as path:
        _write(path, out_repo_id, config, stats, pairs, meta)
        record = {
            "recovery": asdict(recipe),
            "source": {"repo_id": demo_repo_id, "root": str(demo_root), "policy_path": str(policy_path)},
            "result": {
                "rows": len(pairs),
                "synthesised_pairs": int((pairs.source == SYNTHESISED).sum()),
                "demo_pairs": int((pairs.source == FROM_DEMOS).sum()),
                "seconds": round(time.perf_counter() - started, 2),
            },
        }
        (path / RECIPE_COPY).write_text(yaml.safe_dump(record, sort_keys=False))
    logger.info("Wrote %d recovery pairs (%d synthesised, %d from demos) to %s in %.1f s", len(pairs),
                record["result"]["synthesised_pairs"], record["result"]["demo_pairs"], out_root,
                record["result"]["seconds"])
    return Path(out_root)


def _write(path: Path, repo_id: str, config: CCDPConfig, stats: dict, pairs: Pairs, meta: LeRobotDatasetMetadata) -> None:
    """One dataset row per pair, in raw units, with the checkpoint's stats."""
    keys = [OBS_STATE] + ([OBS_ENV_STATE] if config.env_state_feature else [])
    sizes = [config.input_features[k].shape[0] for k in keys]
    raw = unnormalize_batch(config, stats, {
        **dict(zip(keys, pairs.frames.split(sizes, dim=-1), strict=True)),
        FAILURE_FEATURE_KEY: pairs.z_fail,
        ACTION: pairs.actions,
    })
    raw[FAILURE_ACTION] = unnormalize_batch(config, stats, {ACTION: pairs.failure_actions})[ACTION]
    raw[PAIR_SOURCE] = pairs.source[:, None]
    chunk_spec = {"dtype": "float32", "shape": tuple(pairs.actions.shape[1:]), "names": None}
    features = {
        **{k: meta.features[k] for k in keys},
        ACTION: chunk_spec,
        FAILURE_ACTION: chunk_spec,
        FAILURE_FEATURE_KEY: {"dtype": "float32", "shape": (config.failure_feature_dim,), "names": None},
        PAIR_SOURCE: {"dtype": "int64", "shape": (1,), "names": None},
    }
    columns = {k: raw[k].numpy().astype(np.int64 if k == PAIR_SOURCE else np.float32) for k in features}
    task = f"recover from a failure: {meta.tasks.index[0]}" if len(meta.tasks) else "recover from a failure"
    dataset = LeRobotDataset.create(repo_id, fps=meta.fps, features=features, root=path, use_videos=False)
    try:
        for start in range(0, len(pairs), EPISODE_ROWS):
            for row in range(start, min(start + EPISODE_ROWS, len(pairs))):
                dataset.add_frame({**{k: v[row] for k, v in columns.items()}, "task": task})
            dataset.save_episode()
    finally:
        dataset.finalize()
    # The chunk columns' per-frame stats are meaningless for the normaliser: use the checkpoint's, per action dim.
    written = {**dataset.meta.stats}
    for key in [*keys, ACTION, FAILURE_FEATURE_KEY]:
        written[key] = {k: v.numpy() for k, v in stats[key].items()}
    written[FAILURE_ACTION] = written[ACTION]
    write_stats(written, path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recipe", type=Path, help="recipe YAML with a `recovery:` section, e.g. datasets_recipes/door_opening.yaml")
    parser.add_argument("--repo-id", required=True, help="repo id of the local demo dataset, e.g. local/door_opening")
    parser.add_argument("--root", required=True, type=Path, help="folder of the demo dataset")
    parser.add_argument("--policy-path", required=True, type=Path,
                        help="base ccdp checkpoint (a pretrained_model folder written by lerobot-train)")
    parser.add_argument("--out-repo-id", required=True, help="repo id of the recovery dataset, e.g. local/door_opening_recovery")
    parser.add_argument("--out-root", required=True, type=Path, help="folder to write the recovery dataset to")
    parser.add_argument("--overwrite", action="store_true", help="replace --out-root if it exists (once the new one is done)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    recipe = RecoveryRecipe.load(args.recipe)
    synthesize_recovery_dataset(recipe, args.repo_id, args.root, args.policy_path, args.out_repo_id, args.out_root,
                                overwrite=args.overwrite, recipe_source=str(args.recipe))


if __name__ == "__main__":
    main()
