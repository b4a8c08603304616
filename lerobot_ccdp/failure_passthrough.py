"""Backport for LeRobot < 0.5: pass the env's `failure` key through to the policy as `observation.failure`.

LeRobot >= 0.5 passes unknown env observation keys through; 0.4.x's `preprocess_observation` keeps only the
keys it knows, so the policy would never see a failure during `lerobot-eval` or lerobot-train's periodic
eval. Remove this module once the floor is lerobot 0.5.
"""

import functools
import importlib.metadata
import sys

import numpy as np
import torch
from packaging.version import Version

from lerobot_ccdp.configuration_ccdp import FAILURE_FLAG_KEY

ENV_FAILURE_KEY = "failure"


def needs_backport() -> bool:
    return Version(importlib.metadata.version("lerobot")) < Version("0.5")


def install_failure_passthrough() -> None:
    """Wrap lerobot.envs.utils.preprocess_observation, in every module that imported it, once."""
    if not needs_backport():
        return
    import lerobot.envs.utils as env_utils
    import lerobot.scripts.lerobot_eval  # noqa: F401  (binds the name we must replace)

    original = env_utils.preprocess_observation
    if getattr(original, "_ccdp_failure_passthrough", False):
        return

    @functools.wraps(original)
    def preprocess_with_failure(observations: dict) -> dict:
        out = original(observations)
        if ENV_FAILURE_KEY in observations:
            flag = torch.as_tensor(np.asarray(observations[ENV_FAILURE_KEY]), dtype=torch.float32)
            out[FAILURE_FLAG_KEY] = flag.reshape(-1, 1) if flag.ndim <= 1 else flag
        return out

    preprocess_with_failure._ccdp_failure_passthrough = True
    for module in list(sys.modules.values()):
        if getattr(module, "preprocess_observation", None) is original:
            module.preprocess_observation = preprocess_with_failure
