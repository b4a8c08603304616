"""Shared fixtures: a small local 2-D reaching dataset and a ccdp checkpoint trained on it with lerobot-train."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from filelock import FileLock

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("MUJOCO_GL", "egl")

REACHING_REPO_ID = "local/reaching2d"
BIN = Path(sys.executable).parent


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run a LeRobot/lerobot_ccdp console script of this venv, failing the test with its output on error."""
    result = subprocess.run([str(BIN / args[0]), *args[1:]], cwd=cwd, capture_output=True, text=True,
                            env={**os.environ, "HF_HUB_OFFLINE": "1"})
    if result.returncode != 0:
        pytest.fail(f"{' '.join(args)} failed ({result.returncode}):\n{result.stdout[-3000:]}\n{result.stderr[-6000:]}")
    return result


def train_args(root: Path, out: Path, steps: int, *extra: str, batch_size: int = 32) -> list[str]:
    return [
        "lerobot-train", "--policy.type=ccdp", "--policy.failure_feature=primitive", "--policy.num_primitives=4",
        f"--dataset.repo_id={REACHING_REPO_ID}", f"--dataset.root={root}", f"--output_dir={out}",
        f"--steps={steps}", f"--batch_size={batch_size}", "--policy.push_to_hub=false", "--num_workers=0",
        "--wandb.enable=false", "--log_freq=50", "--seed=0", *extra,
    ]


@pytest.fixture(scope="session")
def reaching_root(tmp_path_factory) -> Path:
    from lerobot_ccdp.benchmark.reaching2d import record_reaching_dataset

    root = tmp_path_factory.mktemp("data") / "reaching2d"
    record_reaching_dataset(root, REACHING_REPO_ID, n_episodes=60)
    return root


@pytest.fixture(scope="session")
def trained_run(reaching_root, tmp_path_factory) -> Path:
    """A base-stage ccdp run of 1000 steps of batch 32 (about 4 min on 2 cores), checkpointed at 500 and 1000. Under
    pytest-xdist the first worker to need it trains it in the workers' common folder; the other waits and reuses it."""
    shared = tmp_path_factory.getbasetemp()
    if "PYTEST_XDIST_WORKER" in os.environ:
        shared = shared.parent  # this session's pytest-N folder, above each worker's own
    out = shared / "trained_run"
    with FileLock(f"{out}.lock"):
        if not (out / "checkpoints" / "last").exists():
            shutil.rmtree(out, ignore_errors=True)  # a worker that failed while training leaves no half run
            run_cli(*train_args(reaching_root, out, 1000, "--save_freq=500"))
    return out


@pytest.fixture(scope="session")
def checkpoint(trained_run) -> Path:
    return trained_run / "checkpoints" / "last" / "pretrained_model"


if "PYTEST_XDIST_WORKER" in os.environ:  # two workers on two cores: one thread each, for their CLIs too
    os.environ["OMP_NUM_THREADS"] = "1"
    import torch

    torch.set_num_threads(1)


def _deal_rank(item: pytest.Item) -> int:
    """Where `item`'s file goes in the order `make test` deals files to its two workers (`-n 2 --dist loadfile
    --no-loadscope-reorder`): the reduced pipeline's runs first, then the users of `trained_run` (the first of them
    builds it while the other worker runs the pipeline), the preference family, and the short files behind them."""
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
