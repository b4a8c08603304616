"""Training windows read from column tensors equal LeRobot's own reads, key by key, dtype and all."""

import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset

import lerobot_ccdp  # noqa: F401  (installs the plugin's adaptations, as lerobot-train's plugin import does)
from lerobot_ccdp.benchmark.reaching2d import record_reaching_dataset

from fixtures.reaching import REACHING_REPO_ID

WINDOWS = {"action": [i / 10 for i in range(-1, 16)], "observation.state": [-0.1, 0.0]}


def _dataset(root, episodes: list[int] | None = None) -> LeRobotDataset:
    return LeRobotDataset(REACHING_REPO_ID, root=root, delta_timestamps=WINDOWS, episodes=episodes)


def _same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key, value in a.items():
        if isinstance(value, torch.Tensor):
            assert value.dtype == b[key].dtype and torch.equal(value, b[key]), key
        else:
            assert value == b[key], key


@pytest.mark.parametrize("episodes", [None, [2, 5, 9]], ids=["all", "a subset"])
def test_windows_equal_lerobots_reads_at_every_frame_and_padded_episode_edge(reaching_root, episodes):
    query = LeRobotDataset._query_hf_dataset
    assert query._ccdp_wrapped  # installed on plugin import
    ds = _dataset(reaching_root, episodes)
    if episodes:  # frames are numbered in the whole dataset and read from the subset's rows
        assert ds._absolute_to_relative_idx is not None
    for idx in range(min(len(ds), 400)):  # every frame of the first episodes, their padded edges among them
        indices, _ = ds._get_query_indices(
            ds.hf_dataset[idx]["index"].item(), ds.hf_dataset[idx]["episode_index"].item()
        )
        _same(query(ds, indices), query.__wrapped__(ds, indices))
    item = ds[5]
    assert item["action"].shape == (17, 2) and item["action"].dtype == torch.float32


def test_a_replaced_hf_dataset_is_read_again(reaching_root, tmp_path):
    ds = _dataset(reaching_root)
    before = ds[3]["action"]
    other = tmp_path / "other"
    record_reaching_dataset(other, REACHING_REPO_ID, n_episodes=60, seed=1)
    ds.hf_dataset = _dataset(other).hf_dataset  # what reloading after recording does
    after = ds[3]
    assert not torch.equal(before, after["action"])
    indices, _ = ds._get_query_indices(3, ds.hf_dataset[3]["episode_index"].item())
    _same(
        LeRobotDataset._query_hf_dataset(ds, indices),
        LeRobotDataset._query_hf_dataset.__wrapped__(ds, indices),
    )
