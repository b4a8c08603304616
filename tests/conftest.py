"""Shared fixtures: a small local 2-D reaching dataset and a ccdp checkpoint trained on it with lerobot-train."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

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
    from lerobot_ccdp.reaching2d import record_reaching_dataset

    root = tmp_path_factory.mktemp("data") / "reaching2d"
    record_reaching_dataset(root, REACHING_REPO_ID, n_episodes=60)
    return root


@pytest.fixture(scope="session")
def trained_run(reaching_root, tmp_path_factory) -> Path:
    """A base-stage ccdp run of 1000 steps of batch 32 (about 4 min on 2 cores), checkpointed at 500 and 1000."""
    out = tmp_path_factory.mktemp("runs") / "base"
    run_cli(*train_args(reaching_root, out, 1000, "--save_freq=500"))
    return out


@pytest.fixture(scope="session")
def checkpoint(trained_run) -> Path:
    return trained_run / "checkpoints" / "last" / "pretrained_model"
