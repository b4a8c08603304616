"""Both training stages of ccdp under LeRobot's multi-process launcher, as a user with several GPUs or
machines runs them (`accelerate launch --multi_gpu --num_processes N lerobot-train ...`, README "Several GPUs
or machines"), here as 2-process DDP on the CPU: the base stage trains, the recovery stage trains the head and
leaves the base's weights as they were."""

from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from fixtures.reaching import BIN, REACHING_REPO_ID, run_cli, train_args

LAUNCH = ("accelerate", "launch", "--multi_gpu", "--num_processes=2")
WEIGHTS = "checkpoints/last/pretrained_model/model.safetensors"
RECIPE = Path(__file__).resolve().parents[2] / "datasets_recipes" / "reaching2d.yaml"


@pytest.mark.slow  # about 60 s: two 2-process launches and a synthesis
def test_both_stages_train_as_two_process_ddp(reaching_root, tmp_path):
    base = tmp_path / "base"
    result = run_cli(
        *LAUNCH,
        str(BIN / "lerobot-train"),
        *train_args(reaching_root, base, 40, "--save_freq=40", "--policy.device=cpu")[1:],
    )
    # two processes, one batch each
    assert "Effective batch size: 32 x 2 = 64" in result.stdout + result.stderr
    checkpoint = base / "checkpoints" / "last" / "pretrained_model"
    run_cli(
        "lerobot-ccdp-synthesize",
        f"--config_path={RECIPE}",
        f"--dataset.repo_id={REACHING_REPO_ID}",
        f"--dataset.root={reaching_root}",
        f"--policy.path={checkpoint}",
        "--output.repo_id=local/recovery",
        f"--output.root={tmp_path / 'recovery_data'}",
        "--recovery.n_states=32",
        "--recovery.outcome_radius=0",
    )
    recovery = tmp_path / "recovery"
    run_cli(
        *LAUNCH,
        str(BIN / "lerobot-train"),
        f"--policy.path={checkpoint}",
        "--policy.training_stage=recovery",
        "--policy.device=cpu",
        "--dataset.repo_id=local/recovery",
        f"--dataset.root={tmp_path / 'recovery_data'}",
        f"--output_dir={recovery}",
        "--steps=20",
        "--batch_size=32",
        "--save_freq=20",
        "--num_workers=0",
        "--policy.push_to_hub=false",
        "--wandb.enable=false",
    )
    before, after = load_file(base / WEIGHTS), load_file(recovery / WEIGHTS)
    assert bool(after["model.recovery_trained"]) and not bool(before["model.recovery_trained"])
    assert all(torch.equal(after[k], v) for k, v in before.items() if k.startswith("model.base."))
    head = [k for k in before if k.startswith("model.recovery.")]
    assert head and all(not torch.equal(after[k], before[k]) for k in head)
