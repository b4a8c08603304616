"""An input dimension that never varied in the training data is held at its training value: LeRobot's
normaliser turns its first change into 2e8 (a spread of 0 replaced by 1e-8), which would make every planned
chunk garbage."""

import logging

import pytest
import torch
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.policy.processor_ccdp import make_ccdp_pre_post_processors

STATS = {
    "observation.state": {"min": [-1.0, -1.0], "max": [1.0, 1.0], "mean": [0.0, 0.0], "std": [0.5, 0.5]},
    # dim 1: a flag that was 0 in every training frame (the Bartender's cup3_filled)
    "observation.environment_state": {
        "min": [0.0, 0.0],
        "max": [1.0, 0.0],
        "mean": [0.5, 0.0],
        "std": [0.3, 0.0],
    },
    "action": {"min": [-1.0, -1.0], "max": [1.0, 1.0], "mean": [0.0, 0.0], "std": [0.5, 0.5]},
}


def _policy(env_mode: NormalizationMode = NormalizationMode.MIN_MAX) -> CCDPPolicy:
    config = CCDPConfig(
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (2,)),
            "observation.environment_state": PolicyFeature(FeatureType.ENV, (2,)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
        failure_feature="action",
        horizon=8,
        n_action_steps=4,
        down_dims=(16, 32),
        device="cpu",
        row_noise_streams=False,  # global generator: each _first_action replays its seed's noise
    )
    config.normalization_mapping = {**config.normalization_mapping, "ENV": env_mode}
    torch.manual_seed(0)
    return CCDPPolicy(config, dataset_stats=STATS).eval()


def _first_action(policy: CCDPPolicy, flag: float) -> torch.Tensor:
    pre, post = make_ccdp_pre_post_processors(policy.config, STATS)
    observation = pre(
        {
            "observation.state": torch.tensor([[0.2, -0.3]]),
            "observation.environment_state": torch.tensor([[0.4, flag]]),
        }
    )
    policy.reset()
    torch.manual_seed(1)
    with torch.inference_mode():
        return post(policy.select_action(observation))


def test_lerobots_normaliser_blows_up_a_constant_dimension_that_changes():
    policy = _policy()
    pre, _ = make_ccdp_pre_post_processors(policy.config, STATS)
    normalised = pre(
        {"observation.state": torch.zeros(1, 2), "observation.environment_state": torch.tensor([[0.4, 1.0]])}
    )["observation.environment_state"]
    assert normalised[0, 1] > 1e7  # the hazard the policy guards against


def test_a_changed_constant_dimension_plans_as_at_its_training_value_and_is_logged_once(caplog):
    policy = _policy()
    assert policy.model.constant_inputs.held.tolist() == [False, False, False, True]
    at_training_value = _first_action(policy, 0.0)
    with caplog.at_level(logging.WARNING):
        changed = _first_action(policy, 1.0)
        _first_action(policy, 1.0)
    assert torch.isfinite(changed).all()
    torch.testing.assert_close(changed, at_training_value)
    warnings = [r.getMessage() for r in caplog.records if "never varied" in r.getMessage()]
    assert len(warnings) == 1 and "observation.environment_state[1]" in warnings[0]


def test_without_the_hold_the_changed_dimension_is_refused_naming_it():
    policy = _policy()
    policy.model.constant_inputs.held.zero_()
    with pytest.raises(
        ValueError, match=r"observation\.environment_state\[1\] is 2e\+08 after normalisation"
    ):
        _first_action(policy, 1.0)


def test_mean_std_holds_a_zero_std_dimension():
    policy = _policy(NormalizationMode.MEAN_STD)
    assert policy.model.constant_inputs.held.tolist() == [False, False, False, True]
    assert policy.model.constant_inputs.value[3] == 0.0
    torch.testing.assert_close(_first_action(policy, 1.0), _first_action(policy, 0.0))


def test_the_mask_travels_with_the_checkpoint(tmp_path):
    _policy().save_pretrained(tmp_path)
    loaded = CCDPPolicy.from_pretrained(tmp_path).eval()
    assert loaded.model.constant_inputs.held.tolist() == [False, False, False, True]
    torch.testing.assert_close(_first_action(loaded, 1.0), _first_action(loaded, 0.0))
