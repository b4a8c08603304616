"""Small CCDP policies for unit tests: in-process ones (no dataset), and untrained checkpoints of a dataset."""

from pathlib import Path

import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
from lerobot.datasets.utils import dataset_to_policy_features

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.policy.processor_ccdp import make_ccdp_pre_post_processors

from conftest import REACHING_REPO_ID


def make_policy(state_dim: int = 2, action_dim: int = 2, env_dim: int = 0, **overrides) -> CCDPPolicy:
    inputs = {"observation.state": PolicyFeature(FeatureType.STATE, (state_dim,))}
    if env_dim:
        inputs["observation.environment_state"] = PolicyFeature(FeatureType.ENV, (env_dim,))
    config = CCDPConfig(
        input_features=inputs,
        output_features={"action": PolicyFeature(FeatureType.ACTION, (action_dim,))},
        device="cpu",
        **{"failure_feature": "action", **overrides},
    )
    return CCDPPolicy(config).eval()


def untrained_checkpoint(root: Path, out: Path, repo_id: str = REACHING_REPO_ID, **settings) -> Path:
    """A base-stage checkpoint of the dataset at `root` as lerobot-train writes it (config, weights with the
    outcome table, processors), before any training step."""
    meta = LeRobotDatasetMetadata(repo_id, root=root)
    features = dataset_to_policy_features(meta.features)
    config = CCDPConfig(
        input_features={k: f for k, f in features.items() if f.type is not FeatureType.ACTION},
        output_features={k: f for k, f in features.items() if f.type is FeatureType.ACTION},
        device="cpu", **settings,
    )
    torch.manual_seed(0)
    policy = CCDPPolicy(config, dataset_meta=meta, dataset_stats=meta.stats)
    pre, post = make_ccdp_pre_post_processors(config, meta.stats)
    for item in (policy, pre, post):
        item.save_pretrained(out)
    return out
