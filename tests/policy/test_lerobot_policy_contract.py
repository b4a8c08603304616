"""LeRobot 0.4.4's own policy checks (tests/policies/test_policies.py, those that apply to every policy type),
ported for `ccdp`, with and without cameras.

- test_get_policy_and_config_classes, test_policy_defaults and test_save_and_load_pretrained as LeRobot runs
  them: its dummy dataset (one 84x84 camera, a 6-D state, a 6-D action), default config, bit-identical reload;
- test_policy: make_policy from a dataset's metadata, a few training updates through the processors (the batch
  is not mutated), then select_action under torch.inference_mode() on an env observation (not mutated) and
  env.step; here on a recorded ccdp task, with its camera and without, and with n_obs_steps > 1.
"""

import inspect
from copy import deepcopy

import pytest
import torch
from lerobot.configs.types import FeatureType
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.datasets.utils import dataset_to_policy_features
from lerobot.envs.factory import make_env
from lerobot.envs.utils import preprocess_observation
from lerobot.policies.factory import (
    get_policy_class,
    make_policy,
    make_policy_config,
    make_pre_post_processors,
)
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_IMAGES, OBS_STATE

from lerobot_ccdp.datasets.camera_windows import video_backend
from lerobot_ccdp.datasets.recipe_file import RecordRecipe
from lerobot_ccdp.datasets.record import record_dataset
from lerobot_ccdp.envs import CCDPEnvConfig

TASK = "DoorOpening-lite-v0"
JOINTS = ["shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper"]


@pytest.fixture(params=["camera", "state"])
def dummy_dataset_metadata(request, tmp_path) -> LeRobotDatasetMetadata:
    """LeRobot's dummy metadata: one squared 84x84 camera (or none), a 6-D state and a 6-D action."""
    features = {
        ACTION: {"dtype": "float32", "shape": (6,), "names": JOINTS},
        OBS_STATE: {"dtype": "float32", "shape": (6,), "names": JOINTS},
    }
    if request.param == "camera":
        features[f"{OBS_IMAGES}.laptop"] = {
            "dtype": "video",
            "shape": (84, 84, 3),
            "names": ["height", "width", "channels"],
        }
    return LeRobotDatasetMetadata.create(
        "dummy/repo", fps=30, features=features, root=tmp_path / "init", use_videos=True
    )


def _default_config_for(meta: LeRobotDatasetMetadata):
    config = make_policy_config("ccdp")
    features = dataset_to_policy_features(meta.features)
    config.output_features = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    config.input_features = {k: f for k, f in features.items() if k not in config.output_features}
    return config


def test_get_policy_and_config_classes():
    policy_cls, config = get_policy_class("ccdp"), make_policy_config("ccdp")
    assert policy_cls.name == "ccdp"
    assert issubclass(
        config.__class__, inspect.signature(policy_cls.__init__).parameters["config"].annotation
    )


def test_policy_defaults(dummy_dataset_metadata):
    policy = get_policy_class("ccdp")(_default_config_for(dummy_dataset_metadata))
    assert (policy.model.images is not None) == bool(dummy_dataset_metadata.camera_keys)


def test_save_and_load_pretrained(dummy_dataset_metadata, tmp_path):
    policy_cls = get_policy_class("ccdp")
    config = _default_config_for(dummy_dataset_metadata)
    policy = policy_cls(config)
    policy.to(config.device)
    policy.save_pretrained(tmp_path / "saved")
    loaded = policy_cls.from_pretrained(tmp_path / "saved", config=config)
    torch.testing.assert_close(list(policy.parameters()), list(loaded.parameters()), rtol=0, atol=0)


@pytest.fixture(scope="module", params=["pixels_agent_pos", "state"])
def demos(request, tmp_path_factory) -> tuple[str, LeRobotDataset]:
    """Four expert demos of the door task, observed through its front camera or as state."""
    obs_type = request.param
    root = tmp_path_factory.mktemp(f"contract_{obs_type}") / "demos"
    recipe = RecordRecipe(
        task=TASK,
        n_episodes=4,
        seed=0,
        env_kwargs={"obs_type": obs_type, "observation_width": 32, "observation_height": 32},
    )
    record_dataset(recipe, "local/contract", root, progress=False)
    return obs_type, root


@pytest.mark.parametrize("n_obs_steps", [1, 2])
def test_policy(demos, n_obs_steps):
    obs_type, root = demos
    config = make_policy_config(
        "ccdp",
        n_obs_steps=n_obs_steps,
        history_length=1,
        down_dims=(16, 32),
        horizon=8,
        n_action_steps=4,
        failure_feature="primitive",
        num_primitives=2,
        spatial_softmax_num_keypoints=8,
        vision_backbone_stages=2,
        push_to_hub=False,
        device="cpu",
    )
    meta = LeRobotDatasetMetadata("local/contract", root=root)
    dataset = LeRobotDataset(
        "local/contract",
        root=root,
        delta_timestamps=resolve_delta_timestamps(config, meta),
        video_backend=video_backend(),
    )
    policy = make_policy(config, ds_meta=meta)
    assert isinstance(policy, PreTrainedPolicy)
    assert (policy.model.images is not None) == (obs_type == "pixels_agent_pos")
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=meta.stats)

    loader = torch.utils.data.DataLoader(dataset, batch_size=2, shuffle=True, drop_last=True, num_workers=0)
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=1e-3)
    before = [p.detach().clone() for p in policy.parameters() if p.requires_grad]
    for _, batch in zip(range(3), loader, strict=False):
        batch = preprocessor(batch)
        batch_ = deepcopy(batch)
        loss, _ = policy.forward(batch)
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()
        assert set(batch) == set(batch_), "Batch keys are not the same after a forward pass."
        assert all(
            torch.equal(batch[k], batch_[k]) if isinstance(batch[k], torch.Tensor) else batch[k] == batch_[k]
            for k in batch
        ), "Batch values are not the same after a forward pass."
    after = [p for p in policy.parameters() if p.requires_grad]
    assert any(not torch.equal(a, b) for a, b in zip(after, before, strict=True)), "training updated nothing"
    if policy.model.images is not None:
        encoder = dict(policy.named_parameters())
        assert any(k.startswith("model.images.") for k in encoder), (
            "the camera encoder trains with the base stage"
        )

    policy.eval()
    policy.reset()
    env_config = CCDPEnvConfig(
        task=TASK, obs_type=obs_type, render_mode=None, observation_width=32, observation_height=32
    )
    envs = make_env(env_config, n_envs=2)
    env = next(iter(next(iter(envs.values())).values()))
    try:
        observation, _ = env.reset(seed=0)
        for _ in range(n_obs_steps + 1):  # enough steps for a window of several frames
            observation = preprocessor(preprocess_observation(observation))
            observation_ = deepcopy(observation)
            with torch.inference_mode():
                action = postprocessor(policy.select_action(observation))
            assert set(observation) == set(observation_)
            assert all(
                torch.equal(observation[k], observation_[k])
                for k in observation
                if isinstance(observation[k], torch.Tensor)
            )
            assert action.shape == (2, 4) and torch.isfinite(action).all()
            observation, *_ = env.step(action.numpy())
    finally:
        env.close()
