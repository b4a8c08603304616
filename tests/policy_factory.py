"""Small in-process CCDP policies for unit tests (no dataset needed)."""

from lerobot.configs.types import FeatureType, PolicyFeature

from lerobot_ccdp.configuration_ccdp import CCDPConfig
from lerobot_ccdp.modeling_ccdp import CCDPPolicy


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
