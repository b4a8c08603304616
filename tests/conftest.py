"""Test session settings: offline, headless, one thread per xdist worker, the order files are dealt to
workers; the shared fixtures are plugins under tests/fixtures/."""

import os
from pathlib import Path

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("MUJOCO_GL", "egl")

pytest_plugins = ["fixtures.reaching"]

if "PYTEST_XDIST_WORKER" in os.environ:  # two workers on two cores: one thread each, for their CLIs too
    os.environ["OMP_NUM_THREADS"] = "1"
    import torch

    torch.set_num_threads(1)


def _deal_rank(item: pytest.Item) -> int:
    """Where `item`'s file goes in the order `make test` deals files to its two workers (`-n 2 --dist loadfile
    --no-loadscope-reorder`): the reduced pipeline's runs first, then the users of `trained_run` (the first of
    them builds it while the other worker runs the pipeline), the preference family, and the short files
    behind them."""
    if item.path.name == "test_pipeline.py":
        return 0
    if "trained_run" in item.fixturenames:
        return 1
    return 2 if item.path.name == "test_preferences.py" else 3


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    rank: dict[Path, int] = {}
    for item in items:
        rank[item.path] = min(rank.get(item.path, 3), _deal_rank(item))
    items.sort(key=lambda item: rank[item.path])  # stable: each file's tests stay together and in order
