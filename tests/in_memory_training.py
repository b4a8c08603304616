"""Train one ccdp stage in memory on a LeRobot dataset: lerobot-train's step without its per-step item loading.

On a 2-core CPU lerobot-train spends most of each step reading items from LeRobotDataset. For the CI form of the
preference benchmark every training window is read once, through LeRobotDataset with the policy's delta timestamps
(the windows lerobot-train draws, the last `drop_n_last_frames` of each episode left out as its EpisodeAwareSampler
does); steps then draw shuffled batches from memory through the same preprocessor, loss, optimiser and scheduler
presets and gradient clipping. `benchmarks/bench_preferences.py` trains the same stages with lerobot-train itself.
"""

from pathlib import Path

import torch
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.policies.factory import make_policy, make_pre_post_processors

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy


def dataset_windows(policy: CCDPPolicy, repo_id: str, root: Path) -> dict[str, torch.Tensor]:
    """Every training item of the dataset as the policy's config asks for it, stacked per tensor key."""
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    dataset = LeRobotDataset(repo_id, root=root, delta_timestamps=resolve_delta_timestamps(policy.config, meta))
    drop = policy.config.drop_n_last_frames
    indices = [i for start, end in zip(meta.episodes["dataset_from_index"], meta.episodes["dataset_to_index"],
                                       strict=True) for i in range(start, end - drop)]
    items = [dataset[i] for i in indices]
    return {key: torch.stack([item[key] for item in items]) for key, value in items[0].items()
            if isinstance(value, torch.Tensor)}


def train_in_memory(policy: CCDPPolicy, preprocessor, repo_id: str, root: Path, steps: int, batch_size: int) -> CCDPPolicy:
    """`steps` optimiser steps of the stage `policy.config.training_stage` names, as lerobot-train takes them."""
    windows = dataset_windows(policy, repo_id, root)
    optimizer_config = policy.config.get_optimizer_preset()
    optimizer = optimizer_config.build(policy.get_optim_params())
    scheduler = policy.config.get_scheduler_preset().build(optimizer, num_training_steps=steps)
    count = next(iter(windows.values())).shape[0]
    epochs = -(-steps * batch_size // count)
    order = torch.cat([torch.randperm(count) for _ in range(epochs)])  # shuffled epochs, as the sampler draws them
    policy.train()
    for rows in order[: steps * batch_size].view(steps, batch_size):
        loss, _ = policy.forward(preprocessor({key: value[rows] for key, value in windows.items()}))
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), optimizer_config.grad_clip_norm)
        optimizer.step()
        optimizer.zero_grad()
        scheduler.step()
    return policy.eval()


def train_stage(config: CCDPConfig, repo_id: str, root: Path, out: Path, steps: int, batch_size: int) -> Path:
    """Build the policy as lerobot-train does (`make_policy`; from `config.pretrained_path` when set, as
    --policy.path does), train it in memory and save it with its processors where lerobot-train's last checkpoint
    would be."""
    torch.manual_seed(0)  # lerobot-train seeds before it builds the policy (--seed=0)
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    policy = make_policy(config, ds_meta=meta)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=config.pretrained_path,
                                         dataset_stats=meta.stats)
    train_in_memory(policy, pre, repo_id, root, steps, batch_size)
    for item in (policy, pre, post):
        item.save_pretrained(out)
    return out
