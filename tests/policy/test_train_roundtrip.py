"""Real LeRobot round trips: lerobot-train on a local dataset, reload with --policy.path, --resume, and
save_pretrained/from_pretrained of weights, config and processors."""

import json
import shutil
import sys

import pytest
import torch
from lerobot.policies.factory import make_pre_post_processors
from lerobot.processor import PolicyProcessorPipeline
from lerobot.scripts import lerobot_train

from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

from fixtures.reaching import REACHING_REPO_ID, run_cli, train_args


def test_checkpoint_holds_config_weights_processors_and_outcome_table(trained_checkpoint):
    for name in ("config.json", "model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json"):
        assert (trained_checkpoint / name).is_file(), name
    config = json.loads((trained_checkpoint / "config.json").read_text())
    assert config["type"] == "ccdp" and config["failure_feature"] == "primitive"
    policy = CCDPPolicy.from_pretrained(trained_checkpoint)
    # The table of demonstrated outcomes travelled with the weights: one entry per demo frame, all 4 goals.
    assert len(policy.model.outcomes) == 60 * 32
    assert policy.model.outcomes.primitives.unique().tolist() == [0, 1, 2, 3]
    assert "observation.failure_feature" in policy.config.input_features


def test_save_pretrained_and_from_pretrained_round_trip(trained_checkpoint, tmp_path):
    policy = CCDPPolicy.from_pretrained(trained_checkpoint)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(trained_checkpoint))
    policy.save_pretrained(tmp_path)
    pre.save_pretrained(tmp_path)
    post.save_pretrained(tmp_path)
    again = CCDPPolicy.from_pretrained(tmp_path)
    for key, value in policy.state_dict().items():
        torch.testing.assert_close(again.state_dict()[key], value, msg=key)
    assert again.config == policy.config
    pre2 = PolicyProcessorPipeline.from_pretrained(tmp_path, config_filename="policy_preprocessor.json")
    batch = {"observation.state": torch.tensor([0.3, -0.2]), "action": torch.tensor([0.5, 0.5])}
    torch.testing.assert_close(pre2(dict(batch))["observation.state"], pre(dict(batch))["observation.state"])


@pytest.mark.slow  # its 1000-step training takes about 2.5 min of one worker
def test_trained_policy_reaches_the_demonstrated_goals(skilled_checkpoint):
    """Sanity check that 1000 CPU steps learn the task: every sampled chunk heads to one of the four goals."""
    from lerobot_ccdp.benchmark.reaching2d import GOALS

    policy = CCDPPolicy.from_pretrained(skilled_checkpoint).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(skilled_checkpoint))
    torch.manual_seed(0)
    obs = pre({"observation.state": torch.zeros(1024, 2)})
    chunk = post(policy.predict_action_chunk(obs)).reshape(1024, -1, 2)
    end = chunk[:, -1]  # 0.8 s into the reach
    distance_to_ray = (
        torch.stack(
            [torch.linalg.norm(end - (end @ g)[:, None] * g, dim=-1) for g in torch.from_numpy(GOALS)]
        )
        .min(0)
        .values
    )
    # 1024 samples: 0.77 (batch 32, 1000 steps); 128 samples varied 0.69-0.89 over sampling seeds.
    assert (distance_to_ray < 0.15).float().mean() > 0.7


def test_lerobot_train_from_policy_path(trained_checkpoint, reaching_root, tmp_path):
    out = tmp_path / "finetune"
    args = [a for a in train_args(reaching_root, out, 20) if not a.startswith("--policy.")]
    run_cli(*args, f"--policy.path={trained_checkpoint}", "--policy.push_to_hub=false", "--save_freq=20")
    assert (out / "checkpoints" / "000020" / "pretrained_model" / "model.safetensors").is_file()


@pytest.mark.parametrize("steps", [["--steps=40"], []], ids=["same-steps", "config-steps"])
def test_a_resume_with_nothing_left_to_train_is_refused(trained_run, tmp_path, monkeypatch, steps):
    """LeRobot's loop runs from the saved step to --steps: at 40 of 40 it would train nothing and exit 0."""
    run = tmp_path / "run"
    shutil.copytree(trained_run, run, symlinks=True)
    config = run / "checkpoints" / "last" / "pretrained_model" / "train_config.json"
    config.write_text(json.dumps({**json.loads(config.read_text()), "output_dir": str(run)}))
    argv = ["lerobot-train", f"--config_path={config}", "--resume=true", *steps]
    monkeypatch.setattr(sys, "argv", argv)
    with pytest.raises(
        ValueError, match=r"saved at step 40, and --steps=40 .* nothing is left to train.*--steps=80"
    ):
        lerobot_train.main()
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["000020", "000040", "last"]


def test_lerobot_train_resume(trained_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(trained_run, run, symlinks=True)
    shutil.rmtree(run / "checkpoints" / "000040")
    (run / "checkpoints" / "last").unlink()
    (run / "checkpoints" / "last").symlink_to("000020")
    config = run / "checkpoints" / "000020" / "pretrained_model" / "train_config.json"
    cfg = json.loads(config.read_text())
    cfg["output_dir"] = str(run)
    config.write_text(json.dumps(cfg))
    run_cli("lerobot-train", f"--config_path={config}", "--resume=true", "--steps=30", "--save_freq=8")
    # Resumed at step 20 (a run from scratch would also have saved 000008 and 000016).
    assert sorted(p.name for p in (run / "checkpoints").iterdir() if p.name != "last") == [
        "000020",
        "000024",
        "000030",
    ]
    state = json.loads((run / "checkpoints" / "000030" / "training_state" / "training_step.json").read_text())
    assert state["step"] == 30
    assert (
        REACHING_REPO_ID
        in (run / "checkpoints" / "000030" / "pretrained_model" / "train_config.json").read_text()
    )
