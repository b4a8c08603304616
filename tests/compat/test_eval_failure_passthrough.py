"""lerobot-eval's own rollout loop delivers the env's `failure` key to the policy as `observation.failure`."""

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from lerobot.policies.factory import make_pre_post_processors
from lerobot.processor import PolicyProcessorPipeline
from lerobot.scripts import lerobot_eval

from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

FAIL_AT = (5, 12)


class FlaggingPoint(gym.Env):
    """A 2-D point that flags a failed attempt at fixed steps and puts itself back at the start."""

    metadata = {"render_modes": []}

    def __init__(self):
        self.observation_space = spaces.Dict(
            {
                "agent_pos": spaces.Box(-2, 2, (2,), np.float32),
                "failure": spaces.Box(0, 1, (1,), np.float32),
            }
        )
        self.action_space = spaces.Box(-2, 2, (2,), np.float32)

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.t, self.pos = 0, np.zeros(2, np.float32)
        return self._obs(False), {}

    def step(self, action):
        self.t += 1
        failed = self.t in FAIL_AT
        self.pos = np.zeros(2, np.float32) if failed else np.asarray(action, np.float32)
        return self._obs(failed), 0.0, False, False, {"is_success": False}

    def _obs(self, failed):
        return {"agent_pos": self.pos.copy(), "failure": np.array([float(failed)], np.float32)}


def test_rollout_delivers_failures_to_the_policy(untrained_primitive_checkpoint):
    """What the policy is told, not what it does: an untrained checkpoint serves (no 1000-step training)."""
    gym.register("ccdp_test/FlaggingPoint-v0", entry_point=FlaggingPoint, max_episode_steps=20)
    env = gym.vector.SyncVectorEnv(
        [lambda: gym.make("ccdp_test/FlaggingPoint-v0")] * 2,
        autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
    )
    policy = CCDPPolicy.from_pretrained(untrained_primitive_checkpoint).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(untrained_primitive_checkpoint))
    seen = []
    original = policy.select_action

    def spy(batch, noise=None):
        seen.append(batch.get("observation.failure"))
        return original(batch, noise)

    policy.select_action = spy
    identity = PolicyProcessorPipeline(steps=[])
    lerobot_eval.rollout(env, policy, identity, identity, pre, post, seeds=[0, 1])
    flags = torch.stack([f.reshape(2) for f in seen])
    assert flags.shape == (20, 2)
    assert torch.nonzero(flags[:, 0]).flatten().tolist() == list(FAIL_AT)
    assert policy.failure_count().tolist() == [2, 2]


def _keeping(observations):
    """A LeRobot whose preprocess_observation passes the failure key through itself (as 0.6 is expected
    to)."""
    return {"observation.state": torch.zeros(1, 2), "observation.failure": torch.ones(1, 1)}


def _dropping(observations):
    """A LeRobot whose preprocess_observation keeps only the keys it knows (0.4.x, 0.5.x)."""
    return {"observation.state": torch.zeros(1, 2)}


def test_the_passthrough_installs_only_where_lerobot_drops_the_key(monkeypatch):
    import lerobot.envs.utils as env_utils

    from lerobot_ccdp.compat import failure_passthrough

    monkeypatch.setattr(env_utils, "preprocess_observation", _keeping)
    assert not failure_passthrough.needs_backport()
    failure_passthrough.install_failure_passthrough()
    assert env_utils.preprocess_observation is _keeping

    monkeypatch.setattr(env_utils, "preprocess_observation", _dropping)
    assert failure_passthrough.needs_backport()
    failure_passthrough.install_failure_passthrough()
    wrapped = env_utils.preprocess_observation
    assert wrapped is not _dropping and not failure_passthrough.needs_backport()
    out = wrapped({"agent_pos": np.zeros((1, 2), np.float32), "failure": np.ones((1, 1), np.float32)})
    assert out["observation.failure"].tolist() == [[1.0]]
