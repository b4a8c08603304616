"""Pass the env's `failure` key through to the policy as `observation.failure` where LeRobot drops it.

LeRobot's `preprocess_observation` (0.4.x and 0.5.x) keeps only the keys it knows, so the policy would never
see a failure during `lerobot-eval` or lerobot-train's periodic eval. Whether the installed LeRobot drops it
is detected by calling it, not read from its version number, so the wrapper disappears by itself on a LeRobot
that passes the key through as `observation.failure`.
"""

import functools
import sys

import numpy as np
import torch

from lerobot_ccdp.policy.configuration_ccdp import FAILURE_FLAG_KEY

ENV_FAILURE_KEY = "failure"


def needs_backport() -> bool:
    """Whether LeRobot's preprocess_observation loses an env's `failure` key (probed with a tiny
    observation)."""
    from lerobot.envs.utils import preprocess_observation

    probe = {"agent_pos": np.zeros((1, 2), np.float32), ENV_FAILURE_KEY: np.ones((1, 1), np.float32)}
    return FAILURE_FLAG_KEY not in preprocess_observation(probe)


def install_failure_passthrough() -> None:
    """Wrap lerobot.envs.utils.preprocess_observation, and every already-imported binding of it, once.

    Modules that import it later (lerobot_eval, on a lerobot-eval run) bind the wrapped function."""
    import lerobot.envs.utils as env_utils

    original = env_utils.preprocess_observation
    if getattr(original, "_ccdp_failure_passthrough", False) or not needs_backport():
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
