"""A raw z stored in a recovery dataset, normalised by the policy's preprocessor with
`failure_feature_stats`, equals the z the policy computes at run time from normalised inputs."""

import numpy as np
import pytest
import torch

from lerobot_ccdp.policy.failure_features import failure_feature_stats
from lerobot_ccdp.policy.outcome_index import OutcomeIndex
from lerobot_ccdp.policy.processor_ccdp import make_ccdp_pre_post_processors

from fixtures.policy_factory import make_policy

STATS = {
    "observation.state": {
        "min": np.array([-2.0, 0.0, 1.0]),
        "max": np.array([2.0, 4.0, 3.0]),
        "mean": np.array([0.1, 2.0, 2.0]),
        "std": np.array([1.0, 1.5, 0.5]),
    },
    "action": {
        "min": np.array([-1.0, -3.0]),
        "max": np.array([1.0, 5.0]),
        "mean": np.array([0.0, 1.0]),
        "std": np.array([0.5, 2.0]),
    },
}


@pytest.mark.parametrize("mode", ["MIN_MAX", "MEAN_STD"])
@pytest.mark.parametrize("kind", ["final_state", "action"])
def test_stored_z_normalises_onto_runtime_z(kind, mode):
    from lerobot.configs.types import NormalizationMode

    policy = make_policy(
        state_dim=3,
        failure_feature=kind,
        failure_state_dims=[2, 0],
    )
    for key in ("STATE", "ACTION"):
        policy.config.normalization_mapping[key] = NormalizationMode[mode]
    stats = {**STATS, "observation.failure_feature": failure_feature_stats(policy.config, STATS)}
    pre, _ = make_ccdp_pre_post_processors(policy.config, stats)
    torch.manual_seed(0)
    state, chunk = torch.rand(5, 3) * 2, torch.rand(5, 16, 2)
    raw_z = state[:, [2, 0]] if kind == "final_state" else chunk.flatten(start_dim=1)
    out = pre({"observation.state": state, "action": chunk, "observation.failure_feature": raw_z})
    runtime_z = (
        policy.model.feature.from_frame(out["observation.state"])
        if kind == "final_state"
        else policy.model.feature.from_chunk(out["action"], OutcomeIndex())
    )
    torch.testing.assert_close(out["observation.failure_feature"], runtime_z, atol=1e-5, rtol=1e-5)
