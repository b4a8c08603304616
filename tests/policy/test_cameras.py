"""Cameras end to end: pixel demos in LeRobot's video storage, recovery synthesis that perturbs the state and
reuses the frame's images (eq. 6-7), and the bad inputs a camera policy meets."""

from pathlib import Path

import gymnasium as gym
import pytest
import torch
import yaml
from lerobot.datasets.factory import resolve_delta_timestamps
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.policies.factory import make_pre_post_processors
from lerobot.utils.constants import ACTION, OBS_IMAGES, OBS_STATE

from lerobot_ccdp.benchmark.reaching2d import record_reaching_dataset
from lerobot_ccdp.datasets.camera_windows import CameraWindows, video_backend
from lerobot_ccdp.datasets.recipe_file import RecordRecipe, RecoveryRecipe
from lerobot_ccdp.datasets.record import record_dataset
from lerobot_ccdp.envs import gym_id
from lerobot_ccdp.envs.scripted import Expert, run_episode
from lerobot_ccdp.policy.modeling_ccdp import CCDPModel, CCDPPolicy
from lerobot_ccdp.recovery.synthesize import RECIPE_COPY, synthesize_recovery_dataset

from fixtures.policy_factory import untrained_checkpoint
from fixtures.reaching import REACHING_REPO_ID
from fixtures.recovery_rows import assert_rows_store_the_policys_z

REPO_ID, TASK, SIZE = "local/door_pixels", "DoorOpening-lite-v0", 48
CAMERA = f"{OBS_IMAGES}.front"
PIXELS = {"obs_type": "pixels_agent_pos", "observation_width": SIZE, "observation_height": SIZE}
ENCODER = {"vision_backbone_stages": 3}  # a 3x3 feature map at 48 px
Z_SETTINGS = {
    "primitive": {"failure_feature": "primitive", "num_primitives": 2},
    "final_state": {"failure_feature": "final_state", "failure_state_dims": [0, 1, 2]},
    "action": {"failure_feature": "action"},
}
SMALL = {
    "n_states": 12,
    "chunks_per_state": 4,
    "batch_states": 6,
    "pairs_per_failure": 2,
    "demo_frames": 100,
    "delta_x": 100.0,
    "delta_z": 0.1,
    "sigma": 0.05,
}


@pytest.fixture(scope="module")
def pixel_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("pixels") / "demos"
    record_dataset(
        RecordRecipe(task=TASK, n_episodes=4, seed=0, env_kwargs=PIXELS), REPO_ID, root, progress=False
    )
    return root


def test_pixel_demos_are_stored_as_video_and_decode_to_the_rendered_frames(pixel_root):
    dataset = LeRobotDataset(REPO_ID, root=pixel_root, video_backend=video_backend())
    assert dataset.meta.video_keys == [CAMERA]
    assert "observation.environment_state" not in dataset.features
    env = gym.make(gym_id(TASK), **PIXELS)
    rendered = run_episode(env, Expert(env), seed=0).observations  # recording's first episode: seed 0
    for frame in (0, 10, len(rendered) - 1):
        decoded = dataset[frame][CAMERA]
        assert decoded.shape == (3, SIZE, SIZE) and 0.0 <= float(decoded.min()) <= float(decoded.max()) <= 1.0
        original = torch.from_numpy(rendered[frame]["pixels"]["front"]).permute(2, 0, 1) / 255.0
        assert (decoded - original).abs().mean() < 0.05, "the video holds the rendered frames (lossy codec)"


def test_camera_windows_pad_episode_starts_like_lerobot(pixel_root):
    meta = LeRobotDatasetMetadata(REPO_ID, root=pixel_root)
    windows = CameraWindows(meta, [CAMERA], n_obs_steps=2)(torch.tensor([0, 5]))[CAMERA]
    assert windows.shape == (2, 2, 3, SIZE, SIZE)
    torch.testing.assert_close(windows[0, 0], windows[0, 1])  # frame 0: nothing before it in its episode
    dataset = LeRobotDataset(REPO_ID, root=pixel_root, video_backend=video_backend())
    torch.testing.assert_close(windows[1, 0], dataset[4][CAMERA])
    torch.testing.assert_close(windows[1, 1], dataset[5][CAMERA])


@pytest.fixture(scope="module", params=list(Z_SETTINGS))
def synthesised(request, pixel_root, tmp_path_factory):
    """A recovery dataset from an untrained camera base, with every eq. (7) condition the recipe sampled with
    and the demo frame each condition was built from."""
    settings = Z_SETTINGS[request.param]
    tmp = tmp_path_factory.mktemp(f"pixel_synth_{request.param}")
    checkpoint = untrained_checkpoint(pixel_root, tmp / "base", repo_id=REPO_ID, **ENCODER, **settings)
    conditions, frames = [], []
    sample, windows = CCDPModel.sample_exploratory, CameraWindows.__call__

    def recording_sample(self, state, w_s, noise=None):
        conditions.append(state.clone())
        return sample(self, state, w_s, noise)

    def recording_windows(self, picked):
        frames.append(picked.repeat_interleave(SMALL["chunks_per_state"]))
        return windows(self, picked)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(CCDPModel, "sample_exploratory", recording_sample)
        patch.setattr(CameraWindows, "__call__", recording_windows)
        root = synthesize_recovery_dataset(
            RecoveryRecipe.from_dict(SMALL),
            REPO_ID,
            pixel_root,
            checkpoint,
            "local/recovery",
            tmp / "recovery",
            progress=False,
        )
    return checkpoint, root, torch.cat(conditions), torch.cat(frames)


def test_recovery_rows_carry_no_images_but_the_camera_stats(synthesised, pixel_root):
    checkpoint, root, *_ = synthesised
    recovery = LeRobotDatasetMetadata("local/recovery", root=root)
    assert not recovery.camera_keys and not any("image" in key for key in recovery.features)
    demo_stats = LeRobotDatasetMetadata(REPO_ID, root=pixel_root).stats
    for stat in ("mean", "std"):  # the recovery checkpoint's preprocessor normalises cameras with these
        torch.testing.assert_close(
            torch.as_tensor(recovery.stats[CAMERA][stat]), torch.as_tensor(demo_stats[CAMERA][stat])
        )


def test_camera_rows_store_the_policys_z_of_the_failed_chunk(synthesised):
    checkpoint, root, *_ = synthesised
    assert_rows_store_the_policys_z(checkpoint, root)


def test_eq7_conditions_perturb_the_state_and_reuse_the_frames_images(synthesised, pixel_root):
    """Each condition is [that demo frame's state + N(0, sigma^2), the base's encoding of that frame's
    image]."""
    checkpoint, _, conditions, frames = synthesised
    policy = CCDPPolicy.from_pretrained(checkpoint).eval()
    pre, _ = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    dataset = LeRobotDataset(REPO_ID, root=pixel_root, video_backend=video_backend())
    demo = pre(
        {
            OBS_STATE: torch.stack([dataset[int(i)][OBS_STATE] for i in frames]),
            CAMERA: torch.stack([dataset[int(i)][CAMERA] for i in frames]),
        }
    )
    with torch.no_grad():
        encoded = policy.model.images([demo[CAMERA]])
    state_dim = policy.config.state_dim
    assert conditions.shape == (len(frames), state_dim + encoded.shape[1])
    # The image part is the recorded frame's encoding (to the round-off of encoding in batches of another
    # size).
    torch.testing.assert_close(conditions[:, state_dim:], encoded, atol=1e-3, rtol=1e-3)
    assert torch.cdist(encoded, encoded).max() > 0.1, "the frames' encodings differ, so the check can fail"
    offsets = conditions[:, :state_dim] - demo[OBS_STATE]
    sigma = SMALL["sigma"]
    assert offsets.abs().max() < 6 * sigma and 0.7 * sigma < offsets.std() < 1.3 * sigma


def test_synthesis_record_names_the_camera_dataset(synthesised):
    checkpoint, root, *_ = synthesised
    record = yaml.safe_load((root / RECIPE_COPY).read_text())
    assert record["source"]["policy_path"] == str(checkpoint) and record["result"]["rows"] > 0


def test_a_one_frame_window_from_lerobot_dataset_trains(pixel_root, tmp_path):
    """n_obs_steps=1 without history: LeRobotDataset squeezes the one-frame video window to (C, H, W) while
    the state keeps its window axis; the policy restores the axis instead of refusing the camera."""
    checkpoint = untrained_checkpoint(
        pixel_root,
        tmp_path,
        repo_id=REPO_ID,
        history_length=0,
        n_obs_steps=1,
        **ENCODER,
        **Z_SETTINGS["primitive"],
    )
    policy = CCDPPolicy.from_pretrained(checkpoint).train()
    meta = LeRobotDatasetMetadata(REPO_ID, root=pixel_root)
    delta = resolve_delta_timestamps(policy.config, meta)
    dataset = LeRobotDataset(REPO_ID, root=pixel_root, delta_timestamps=delta, video_backend=video_backend())
    batch = next(iter(torch.utils.data.DataLoader(dataset, batch_size=4)))
    assert batch[CAMERA].shape == (4, 3, SIZE, SIZE) and batch[OBS_STATE].shape[:2] == (4, 1)
    preprocessor, _ = make_pre_post_processors(policy.config, checkpoint)
    loss, _ = policy.forward(preprocessor(batch))
    assert torch.isfinite(loss)


# ----- bad input --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def camera_policy(pixel_root, tmp_path_factory) -> CCDPPolicy:
    out = tmp_path_factory.mktemp("camera_policy")
    return CCDPPolicy.from_pretrained(
        untrained_checkpoint(pixel_root, out, repo_id=REPO_ID, **ENCODER, **Z_SETTINGS["primitive"])
    ).eval()


def test_a_camera_of_another_size_names_the_key_and_the_fix(camera_policy):
    batch = {OBS_STATE: torch.zeros(1, 4), CAMERA: torch.zeros(1, 3, SIZE + 16, SIZE)}
    with pytest.raises(ValueError, match=rf"{CAMERA}.*expects \(1, 3, {SIZE}, {SIZE}\).*observation_height"):
        camera_policy.select_action(batch)


def test_a_missing_camera_names_the_key(camera_policy):
    with pytest.raises(KeyError, match=f"needs '{CAMERA}'"):
        camera_policy.select_action({OBS_STATE: torch.zeros(1, 4)})


def test_state_observations_for_a_camera_checkpoint_name_what_it_needs(camera_policy):
    batch = {OBS_STATE: torch.zeros(1, 4), "observation.environment_state": torch.zeros(1, 6)}
    with pytest.raises(KeyError, match=f"needs '{CAMERA}'"):
        camera_policy.select_action(batch)


def test_cameras_for_a_state_checkpoint_name_the_obs_type(tmp_path):
    record_reaching_dataset(tmp_path / "r2d", REACHING_REPO_ID, n_episodes=4)
    policy = CCDPPolicy.from_pretrained(
        untrained_checkpoint(tmp_path / "r2d", tmp_path / "ckpt", **Z_SETTINGS["action"])
    ).eval()
    with pytest.raises(KeyError, match="holds cameras.*--env.obs_type"):
        policy.select_action({CAMERA: torch.zeros(1, 3, SIZE, SIZE)})
    policy.train()
    batch = {
        OBS_STATE: torch.zeros(2, 3, 2),
        CAMERA: torch.zeros(2, 3, 3, SIZE, SIZE),
        ACTION: torch.zeros(2, 18, 2),
    }
    with pytest.raises(
        ValueError, match=rf"cameras \['{CAMERA}'\] that this policy does not encode.*new base stage"
    ):
        policy.forward(batch)


def test_images_too_small_for_the_backbone_name_the_fix(pixel_root, tmp_path):
    with pytest.raises(ValueError, match=r"1x1 feature map after 4 ResNet stages.*vision_backbone_stages"):
        untrained_checkpoint(
            pixel_root, tmp_path, repo_id=REPO_ID, resize_shape=(32, 32), **Z_SETTINGS["primitive"]
        )
