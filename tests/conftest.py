"""Test session settings: offline, headless, one thread per xdist worker, the order files are dealt to
workers; the shared fixtures are plugins under tests/fixtures/."""

import os
from pathlib import Path

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("MUJOCO_GL", "egl")

pytest_plugins = ["fixtures.reaching", "fixtures.lite_eval"]

if "PYTEST_XDIST_WORKER" in os.environ:  # two workers on two cores: one thread each, for their CLIs too
    os.environ["OMP_NUM_THREADS"] = "1"
    import torch

    torch.set_num_threads(1)


# The files of a minute or more of setup, longest first: dealt before the rest, so that neither ends the run
# with the other worker idle (the set-denoiser claim among the short files: 746 s of tests; first: 671 s).
FIRST = ("test_pipeline.py", "test_set_denoiser_claim.py")
# Files of several slow tests each, dealt after the users of `trained_run`, before the short files.
HEAVY = ("test_synthesis.py", "test_experts.py", "test_policy_safety.py")
LAST = len(FIRST) + 2


def _deal_rank(item: pytest.Item) -> int:
    """Where `item`'s file goes in the order `make test` deals files to its two workers (`-n 2 --dist loadfile
    --no-loadscope-reorder`): the reduced pipeline's runs and the set-denoiser claim first, one per worker,
    then the users of `trained_run` (the first of them builds it while the other worker still runs the
    pipeline), the heavy files, and the short files behind them."""
    if item.path.name in FIRST:
        return FIRST.index(item.path.name)
    if "trained_run" in item.fixturenames:
        return len(FIRST)
    return len(FIRST) + 1 if item.path.name in HEAVY else LAST


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    rank: dict[Path, int] = {}
    for item in items:
        rank[item.path] = min(rank.get(item.path, LAST), _deal_rank(item))
    items.sort(key=lambda item: rank[item.path])  # stable: each file's tests stay together and in order
