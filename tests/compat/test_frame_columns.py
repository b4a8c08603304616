"""Training items and windows read from column tensors equal LeRobot's own reads, key by key and dtype."""

import logging
import pickle

import pytest
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset

import lerobot_ccdp  # noqa: F401  (installs the plugin's adaptations, as lerobot-train's plugin import does)
from lerobot_ccdp.benchmark.reaching2d import record_reaching_dataset
from lerobot_ccdp.compat import frame_columns

from fixtures.reaching import REACHING_REPO_ID

WINDOWS = {"action": [i / 10 for i in range(-1, 16)], "observation.state": [-0.1, 0.0]}


def _dataset(root, episodes: list[int] | None = None, windows: dict | None = WINDOWS) -> LeRobotDataset:
    return LeRobotDataset(REACHING_REPO_ID, root=root, delta_timestamps=windows, episodes=episodes)


def _same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key, value in a.items():
        if isinstance(value, torch.Tensor):
            assert value.dtype == b[key].dtype and torch.equal(value, b[key]), key
        else:
            assert value == b[key], key


@pytest.mark.parametrize(
    "episodes, windows",
    [(None, WINDOWS), ([2, 5, 9], WINDOWS), (None, None)],
    ids=["all", "a subset", "no windows"],
)
def test_items_equal_lerobots_at_every_frame_and_padded_episode_edge(reaching_root, episodes, windows):
    own = LeRobotDataset.__getitem__.__wrapped__
    assert LeRobotDataset.__getitem__._ccdp_wrapped and LeRobotDataset._query_hf_dataset._ccdp_wrapped
    ds = _dataset(reaching_root, episodes, windows)
    if episodes:  # frames are numbered in the whole dataset and read from the subset's rows
        assert ds._absolute_to_relative_idx is not None
    for idx in range(min(len(ds), 400)):  # every frame of the first episodes, their padded edges among them
        _same(ds[idx], own(ds, idx))
    assert getattr(ds, frame_columns._CACHE).items  # whole items came from the columns
    if windows:
        assert ds[5]["action"].shape == (17, 2) and ds[5]["action"].dtype == torch.float32
    item = ds[7]
    item["action"] += 1  # an item's tensors are its own, not views of the held columns
    _same(ds[7], own(ds, 7))


def test_a_lerobot_that_assembles_items_otherwise_keeps_its_own_path(reaching_root, monkeypatch, caplog):
    ds = _dataset(reaching_root)
    calls = []

    def other_item(dataset, idx):
        calls.append(idx)
        return {**LeRobotDataset.__getitem__.__wrapped__(dataset, idx), "extra": torch.zeros(1)}

    monkeypatch.setattr(frame_columns, "_item", other_item)
    with caplog.at_level(logging.WARNING):
        first = ds[3]
    assert "extra" not in first and "assembles dataset items differently" in caplog.text
    _same(ds[4], LeRobotDataset.__getitem__.__wrapped__(ds, 4))
    assert calls == [3]  # compared once, then LeRobot's own path


def test_a_replaced_hf_dataset_is_read_again(reaching_root, tmp_path):
    ds = _dataset(reaching_root)
    before = ds[3]["action"]
    other = tmp_path / "other"
    record_reaching_dataset(other, REACHING_REPO_ID, n_episodes=60, seed=1)
    ds.hf_dataset = _dataset(other).hf_dataset  # what reloading after recording does
    after = ds[3]
    assert not torch.equal(before, after["action"])
    _same(after, LeRobotDataset.__getitem__.__wrapped__(ds, 3))


def test_a_dataset_sent_to_a_worker_reads_its_columns_again(reaching_root):
    """DataLoader workers started with `spawn` (macOS, Windows) receive the dataset pickled."""
    ds = _dataset(reaching_root)
    first = ds[3]
    copy = pickle.loads(pickle.dumps(ds))
    assert getattr(copy, frame_columns._CACHE) is None
    _same(copy[3], first)
    assert getattr(copy, frame_columns._CACHE).items
