"""A failure reaches ccdp inside lerobot-record's loop through `--policy.failure_signal_file`.

The policy and processors are made exactly as
`lerobot-record --policy.path=... --policy.failure_signal_file=...` makes them (config with the CLI override,
make_policy on the new recording dataset's metadata, make_pre_post_processors), and LeRobot's own
`record_loop` drives a simulated 2-D robot with the methods the loop calls (get_observation, send_action,
robot_type). The robot's "detector" creates the file mid-episode, as a robot owner's script or key handler
would.
"""

import logging
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.datasets.utils import hw_to_dataset_features
from lerobot.policies.factory import make_policy, make_pre_post_processors
from lerobot.processor import make_default_processors
from lerobot.scripts.lerobot_record import record_loop
from lerobot.utils.constants import ACTION, OBS_STR

from lerobot_ccdp.benchmark.reaching2d import FPS

from fixtures import policy_factory
from fixtures.policy_factory import untrained_checkpoint
from fixtures.reaching import REACHING_REPO_ID

MOTORS = {"x": float, "y": float}


class SimReacher:
    """A point robot that moves to the commanded position; touches `signal` after `fail_at` actions (its
    failure detector) and ends the episode after `steps` actions, through lerobot-record's own event."""

    robot_type = name = "sim_reacher"

    def __init__(self, events: dict, steps: int, signal: Path | None = None, fail_at: int = -1):
        self.events, self.steps, self.signal, self.fail_at = events, steps, signal, fail_at
        self.position, self.sent = np.zeros(2, dtype=np.float32), 0
        self.observation_features = self.action_features = MOTORS

    def get_observation(self) -> dict[str, float]:
        return {"x": float(self.position[0]), "y": float(self.position[1])}

    def send_action(self, action: dict[str, float]) -> dict[str, float]:
        self.position = np.array([action["x"], action["y"]], dtype=np.float32)
        self.sent += 1
        if self.sent == self.fail_at:
            self.signal.touch()
        if self.sent >= self.steps:
            self.events["exit_early"] = True
        return action


@pytest.fixture
def action_checkpoint(reaching_root, tmp_path) -> Path:
    return untrained_checkpoint(reaching_root, tmp_path / "ckpt", failure_feature="action")


def _record_setup(action_checkpoint: Path, tmp_path: Path, *overrides: str):
    """What lerobot-record builds from --policy.path and --dataset.* before its loop."""
    config = PreTrainedConfig.from_pretrained(action_checkpoint, cli_overrides=list(overrides))
    config.pretrained_path = action_checkpoint
    features = {**hw_to_dataset_features(MOTORS, ACTION), **hw_to_dataset_features(MOTORS, OBS_STR)}
    dataset = LeRobotDataset.create(
        f"{REACHING_REPO_ID}_eval", fps=FPS, features=features, root=tmp_path / "recording", use_videos=False
    )
    policy = make_policy(config, ds_meta=dataset.meta)
    pre, post = make_pre_post_processors(
        policy_cfg=config,
        pretrained_path=config.pretrained_path,
        dataset_stats=dataset.meta.stats,
        preprocessor_overrides={
            "device_processor": {"device": config.device},
            "rename_observations_processor": {"rename_map": {}},
        },
    )
    return policy, pre, post, dataset


def _episode(robot: SimReacher, events: dict, policy, pre, post, dataset) -> None:
    teleop_action, robot_action, robot_observation = make_default_processors()
    record_loop(
        robot=robot,
        events=events,
        fps=FPS,
        teleop_action_processor=teleop_action,
        robot_action_processor=robot_action,
        robot_observation_processor=robot_observation,
        dataset=dataset,
        policy=policy,
        preprocessor=pre,
        postprocessor=post,
        control_time_s=10_000,  # the robot ends the episode, not the clock
        single_task="reach",
    )


def test_a_failure_signal_file_reaches_ccdp_inside_lerobot_record(action_checkpoint, tmp_path):
    signal = tmp_path / "ccdp_failed"
    signal.write_text("left over from an earlier run: not a failure of this one\n")
    os.utime(signal, ns=(0, 0))  # so that the robot's touch below changes its time on any file system
    policy, pre, post, dataset = _record_setup(action_checkpoint, tmp_path, f"--failure_signal_file={signal}")
    assert policy.config.failure_signal_file == str(signal)

    events = {"exit_early": False, "rerecord_episode": False, "stop_recording": False}
    robot = SimReacher(events, steps=12, signal=signal, fail_at=5)
    _episode(robot, events, policy, pre, post, dataset)

    assert robot.sent == 12
    assert policy.failure_count().tolist() == [1], "the failure signal did not reach the policy"
    assert signal.read_text().startswith("left over"), "the policy never deletes or writes the user's file"
    assert dataset.episode_buffer["size"] == 12  # lerobot-record wrote the frames as usual

    # The next episode (record_loop resets the policy) starts with no failures.
    events["exit_early"] = False
    _episode(SimReacher(events, steps=3), events, policy, pre, post, dataset)
    assert policy.failure_count().tolist() == [0]


def test_an_episode_without_any_failure_source_is_reported_once(action_checkpoint, tmp_path, caplog):
    policy, pre, post, dataset = _record_setup(action_checkpoint, tmp_path)
    events = {"exit_early": False, "rerecord_episode": False, "stop_recording": False}
    with caplog.at_level(logging.WARNING, logger="lerobot_ccdp.policy.failure_signal"):
        for _ in range(3):  # each record_loop resets the policy: the end of the episode before
            events["exit_early"] = False
            _episode(SimReacher(events, steps=2), events, policy, pre, post, dataset)
    deaf = [r for r in caplog.records if "nothing could tell it about a failure" in r.getMessage()]
    assert len(deaf) == 1 and "--policy.failure_signal_file" in deaf[0].getMessage()


def test_a_signal_file_in_a_missing_folder_is_refused_with_the_fix(action_checkpoint, tmp_path):
    missing = tmp_path / "no_such_folder" / "ccdp_failed"
    with pytest.raises(ValueError, match=r"does not exist\. Create the folder"):
        _record_setup(action_checkpoint, tmp_path, f"--failure_signal_file={missing}")


def test_with_recovery_off_no_warning(action_checkpoint, tmp_path, caplog):
    policy, pre, post, dataset = _record_setup(action_checkpoint, tmp_path, "--recovery_mode=dp")
    events = {"exit_early": False, "rerecord_episode": False, "stop_recording": False}
    with caplog.at_level(logging.WARNING, logger="lerobot_ccdp.policy.failure_signal"):
        for _ in range(2):
            events["exit_early"] = False
            _episode(SimReacher(events, steps=2), events, policy, pre, post, dataset)
    assert not [r for r in caplog.records if "nothing could tell it" in r.getMessage()]
    assert torch.equal(policy.failure_count(), torch.zeros(1, dtype=torch.long))


def test_the_warning_follows_the_mode_the_episode_planned_in(caplog):
    """An episode planned as plain DP, with the mode switched to ccdp before reset() (as the option-share
    benchmarks do), did not run with recovery on: no warning. One planned in ccdp mode does warn."""
    policy = policy_factory.make_policy()
    obs = {"observation.state": torch.zeros(1, 2)}
    with caplog.at_level(logging.WARNING, logger="lerobot_ccdp.policy.failure_signal"):
        policy.config.recovery_mode = "dp"
        policy.select_action(obs)
        policy.config.recovery_mode = "ccdp"
        policy.reset()
        assert not [r for r in caplog.records if "nothing could tell it" in r.getMessage()]
        policy.select_action(obs)
        policy.reset()
    assert len([r for r in caplog.records if "nothing could tell it" in r.getMessage()]) == 1
