"""Pre- and post-processors of the CCDP policy (LeRobot finds `make_ccdp_pre_post_processors` by name)."""

from typing import Any

import torch
from lerobot.processor import (
    AddBatchDimensionProcessorStep,
    DeviceProcessorStep,
    NormalizerProcessorStep,
    PolicyAction,
    PolicyProcessorPipeline,
    RenameObservationsProcessorStep,
    UnnormalizerProcessorStep,
)
from lerobot.processor.converters import (
    batch_to_transition,
    policy_action_to_transition,
    transition_to_batch,
    transition_to_policy_action,
)
from lerobot.utils.constants import POLICY_POSTPROCESSOR_DEFAULT_NAME, POLICY_PREPROCESSOR_DEFAULT_NAME

from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig


def make_ccdp_pre_post_processors(
    config: CCDPConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    """Rename, batch, move to device and normalise every input the policy reads, the failure feature z
    (FAILURE_FEATURE_KEY) included; unnormalise actions on the way out. Both pipelines are saved and reloaded
    with the policy, stats included."""
    input_steps = [
        RenameObservationsProcessorStep(rename_map={}),
        AddBatchDimensionProcessorStep(),
        DeviceProcessorStep(device=config.device),
        _normalizer(config, dataset_stats),
    ]
    output_steps = [
        UnnormalizerProcessorStep(
            features=config.output_features, norm_map=config.normalization_mapping, stats=dataset_stats
        ),
        DeviceProcessorStep(device="cpu"),
    ]
    return (
        PolicyProcessorPipeline[dict[str, Any], dict[str, Any]](
            steps=input_steps, name=POLICY_PREPROCESSOR_DEFAULT_NAME
        ),
        PolicyProcessorPipeline[PolicyAction, PolicyAction](
            steps=output_steps,
            name=POLICY_POSTPROCESSOR_DEFAULT_NAME,
            to_transition=policy_action_to_transition,
            to_output=transition_to_policy_action,
        ),
    )


def normalize_batch(config: CCDPConfig, stats: dict, batch: dict[str, Any]) -> dict[str, Any]:
    """Normalise a batch exactly as the policy's preprocessor does (for code that reads datasets directly)."""
    return transition_to_batch(_normalizer(config, stats)(batch_to_transition(batch)))


def unnormalize_batch(config: CCDPConfig, stats: dict, batch: dict[str, Any]) -> dict[str, Any]:
    """Invert `normalize_batch` (for code that writes datasets from the policy's normalised space)."""
    return transition_to_batch(
        _normalizer(config, stats, UnnormalizerProcessorStep)(batch_to_transition(batch))
    )


def _normalizer(
    config: CCDPConfig, stats: dict | None, step: type = NormalizerProcessorStep
) -> NormalizerProcessorStep | UnnormalizerProcessorStep:
    return step(
        features={**config.input_features, **config.output_features},
        norm_map=config.normalization_mapping,
        stats=stats,
    )
