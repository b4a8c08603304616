"""Where demonstrated options end without labels: at gripper releases or at pauses, never across an
episode."""

from pathlib import Path

import numpy as np
import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.datasets.utils import dataset_to_policy_features

from lerobot_ccdp.benchmark import segment_agreement
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.demo_segments import segment_ends, segment_final_states
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

REPO = Path(__file__).resolve().parents[2]

# Two episodes of a pick and place: move, grasp (gripper 1), carry, release (gripper 0), then move on.
EPISODES = np.array([0] * 8 + [1] * 5)
GRIPPER = np.array([0, 0, 1, 1, 1, 0, 0, 0] + [0, 1, 1, 0, 0], dtype=float)
POSITION = np.array([0, 1, 1, 2, 3, 3, 4, 5] + [0, 0, 1, 1, 2], dtype=float)
ACTIONS = np.stack([POSITION, GRIPPER], axis=1)


def ends_of(rule: str, **kwargs) -> list[int]:
    return np.flatnonzero(segment_ends(rule, EPISODES, ACTIONS, **kwargs)).tolist()


def test_releases_end_an_option_at_the_last_frame_the_gripper_holds():
    assert ends_of("releases") == [4, 7, 10, 12]


def test_drops_keep_the_opening_command_and_the_still_frames_after_it_in_the_option():
    # Frames 5 and 11 open the hand where it stands; the arm moves on at frames 6 and 12.
    assert ends_of("drops") == [5, 7, 11, 12]
    # A demonstrator who holds still for two frames after opening (frames 6, 7): the option ends at frame 7.
    held = ACTIONS.copy()
    held[6, 0] = held[7, 0] = 3
    assert np.flatnonzero(segment_ends("drops", EPISODES, held)).tolist() == [7, 11, 12]
    assert np.flatnonzero(segment_ends("releases", EPISODES, held)).tolist() == [4, 7, 10, 12]


def test_release_is_a_return_to_the_side_the_gripper_started_on():
    # A hand that starts closed (holding a bottle) and opens once has not released anything yet when it opens.
    assert ends_of("releases", gripper_dim=1) == ends_of("releases")
    flipped = ACTIONS.copy()
    flipped[:, 1] = 1 - flipped[:, 1]
    assert np.flatnonzero(segment_ends("releases", EPISODES, flipped)).tolist() == [4, 7, 10, 12]
    always_closed = flipped.copy()
    always_closed[:, 1] = 1.0
    assert np.flatnonzero(segment_ends("releases", EPISODES, always_closed)).tolist() == [7, 12]


def test_pauses_end_where_every_action_dim_held_still_long_enough():
    # The position holds at frames 2, 5 and 11, but the gripper changes there: no frame is still.
    assert ends_of("pauses") == [7, 12]
    # the same path with the gripper never moving
    held = np.stack([POSITION, np.zeros_like(POSITION)], axis=1)
    assert np.flatnonzero(segment_ends("pauses", EPISODES, held, pause_steps=1)).tolist() == [
        2,
        5,
        7,
        9,
        11,
        12,
    ]
    assert np.flatnonzero(segment_ends("pauses", EPISODES, held, pause_steps=2)).tolist() == [7, 12]


def test_a_pause_does_not_run_on_from_the_previous_episode():
    episodes = np.array([0, 0, 1, 1, 1])
    actions = np.array([[0.0], [5.0], [5.0], [5.0], [6.0]])  # episode 1 starts where episode 0 stopped
    assert np.flatnonzero(segment_ends("pauses", episodes, actions, pause_steps=2)).tolist() == [1, 4]
    assert np.flatnonzero(segment_ends("pauses", episodes, actions, pause_steps=1)).tolist() == [1, 3, 4]


def test_labels_end_each_run_of_one_label_and_without_labels_the_episode():
    labels = np.array([0, 0, 0, 0, 0, 1, 1, 1] + [2, 2, 2, 2, 2])
    assert ends_of("labels", labels=labels) == [4, 7, 12]
    assert ends_of("labels") == [7, 12]


def test_each_frame_gets_the_state_at_the_first_segment_end_at_or_after_it():
    states = np.arange(13, dtype=float)[:, None] * 10
    finals = segment_final_states(states, segment_ends("releases", EPISODES, ACTIONS))
    assert finals[:, 0].tolist() == [40] * 5 + [70] * 3 + [100] * 3 + [120] * 2


def test_unknown_rules_and_impossible_settings_are_refused_with_the_fix():
    with pytest.raises(ValueError, match="failure_segments"):
        CCDPConfig(failure_segments="keyframes")
    with pytest.raises(ValueError, match="segment rule"):
        segment_ends("gripper", EPISODES, ACTIONS)


def test_the_policy_gives_each_demonstrated_chunk_the_state_where_its_gripper_let_go(tmp_path):
    """`--policy.failure_segments=drops` reaches the outcome table a checkpoint keeps: a frame's final state
    is the normalised state where its option's release ends, not at its episode's end."""
    features = {
        "observation.state": {"dtype": "float32", "shape": (2,), "names": None},
        "action": {"dtype": "float32", "shape": (2,), "names": None},
    }
    dataset = LeRobotDataset.create(
        "local/releases", fps=10, features=features, root=tmp_path / "d", use_videos=False
    )
    for episode in (0, 1):
        frames = EPISODES == episode
        for state, action in zip(ACTIONS[frames], ACTIONS[frames], strict=True):
            dataset.add_frame(
                {
                    "observation.state": state.astype(np.float32),
                    "action": action.astype(np.float32),
                    "task": "pick and place",
                }
            )
        dataset.save_episode()
    dataset.finalize()
    meta = LeRobotDatasetMetadata("local/releases", root=tmp_path / "d")
    policy_features = dataset_to_policy_features(meta.features)
    config = CCDPConfig(
        input_features={"observation.state": policy_features["observation.state"]},
        output_features={"action": policy_features["action"]},
        device="cpu",
        horizon=8,
        n_action_steps=4,
        down_dims=(32, 64),
        failure_feature="final_state",
        failure_state_dims=[0],
        failure_segments="drops",
    )
    policy = CCDPPolicy(config, dataset_meta=meta, dataset_stats=meta.stats)
    low, high = POSITION.min(), POSITION.max()
    expected = (
        2
        * (segment_final_states(POSITION[:, None], segment_ends("drops", EPISODES, ACTIONS)) - low)
        / (high - low)
        - 1
    )
    torch.testing.assert_close(
        policy.model.outcomes.final_states, torch.tensor(expected, dtype=torch.float32)
    )


def test_segment_agreement_scores_the_frames_whose_label_free_end_misses_their_labelled_one():
    labels = np.array([0, 0, 0, 0, 0, 1, 1, 1] + [2] * 5)  # labelled ends 4, 7, 12; releases end 4, 7, 10, 12
    columns = {
        "episode_index": EPISODES,
        "observation.state": np.stack([POSITION, np.zeros(13)], axis=1),
        "action": ACTIONS,
        "primitive": labels,
    }
    share, per_episode = segment_agreement.agreement(columns, "releases", tolerance=0.02)
    # frames 8-10 end at 1, their label's end at 2
    assert (share, per_episode) == (pytest.approx(10 / 13), 2.0)
    # Without labels, frames 0-4 end with their episode at 5, where their labelled option ends at 3.
    assert segment_agreement.agreement(columns, "labels", tolerance=0.02) == (pytest.approx(8 / 13), 1.0)
