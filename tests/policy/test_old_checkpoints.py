"""A checkpoint written before the recovery heads became modules of their own (commit 0032ef5) still loads,
and every head acts and trains as it did then.

A trained checkpoint of each head is about 1 MB, so tests/policy/old_layout/ keeps what the old code wrote
that cannot be rebuilt, and is small: each head's config.json as saved then, the names, shapes and dtypes of
its weights, and the figures the old code computed (actions after failures, each stage's loss). The test
writes the weights under those names with seeded values, loads the folder with `CCDPPolicy.from_pretrained`
and compares the figures. `python tests/policy/test_old_checkpoints.py` writes the data anew from the code it
imports (it was run at 0032ef5); never run it to make a failing test pass.
"""

import json
import sys
from pathlib import Path

import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from safetensors.torch import save_file

from lerobot_ccdp.policy.configuration_ccdp import FAILURE_FEATURE_KEY, CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

DATA = Path(__file__).resolve().parent / "old_layout"
HEADS = {
    "unet": {},
    "classifier": {},
    "set_denoiser": {"failure_guard_steps": 2, "w_z": 1.5, "w_z_steps": 6},
}
ROWS, STATE_DIM, ACTION_DIM = 6, 2, 2
SIZES = {"horizon": 8, "n_action_steps": 4, "down_dims": (16, 32), "diffusion_step_embed_dim": 16}


def seeded_weights(layout: dict[str, list]) -> dict[str, torch.Tensor]:
    """Small seeded values under the saved names, drawn in name order; flags (bool) as saved."""
    generator = torch.Generator().manual_seed(0)
    weights = {}
    for name, (shape, dtype, *flags) in sorted(layout.items()):
        if flags:
            weights[name] = torch.tensor(flags[0], dtype=torch.bool).reshape(shape)
        else:
            weights[name] = 0.2 * torch.randn(shape, generator=generator, dtype=getattr(torch, dtype[6:]))
    return weights


def figures(policy: CCDPPolicy) -> dict[str, list]:
    """Actions before and after two reported failures, then each stage's loss on a fixed batch."""
    torch.manual_seed(1)
    batch = {"observation.state": torch.linspace(-1, 1, ROWS * STATE_DIM).view(ROWS, STATE_DIM)}
    with torch.inference_mode():
        policy.reset()
        first = policy.select_action(batch)
        for option in (0.5, -0.5):
            policy.report_failure(z=torch.full((ROWS, policy.config.failure_feature_dim), option))
        after = torch.stack([policy.select_action(batch) for _ in range(policy.config.n_action_steps)])
    cfg = policy.config
    chunks = torch.randn(ROWS, cfg.horizon + cfg.n_obs_steps - 1, ACTION_DIM)
    state = torch.randn(ROWS, cfg.n_obs_steps, STATE_DIM)
    losses = {}
    for stage in ("base", "recovery"):
        cfg.training_stage = stage
        torch.manual_seed(2)
        if stage == "base" or policy.model.config.recovery_head == "classifier":
            train = {"observation.state": state, "action": chunks}
        else:
            train = {
                "observation.state": state[:, -1],
                "action": chunks[:, : cfg.horizon],
                FAILURE_FEATURE_KEY: torch.randn(ROWS, cfg.failure_feature_dim),
            }
        losses[stage] = policy.model.compute_loss(train)[0].item()
    cfg.training_stage = "recovery"
    return {"first": first.tolist(), "after_failures": after.tolist(), "losses": losses}


def write_old_checkpoint(head: str, folder: Path) -> Path:
    """The saved config.json and seeded weights under the old names: a checkpoint as the old code wrote it."""
    folder.mkdir(parents=True)
    (folder / "config.json").write_text((DATA / head / "config.json").read_text())
    layout = json.loads((DATA / head / "weights.json").read_text())
    save_file(seeded_weights(layout), str(folder / "model.safetensors"))
    return folder


@pytest.mark.parametrize("head", list(HEADS))
def test_a_checkpoint_of_the_old_layout_loads_and_acts_and_trains_as_before(head, tmp_path):
    policy = CCDPPolicy.from_pretrained(write_old_checkpoint(head, tmp_path / head))
    # the head its config.json names, not the default for its state inputs
    assert policy.model.head.name == head and bool(policy.model.recovery_trained)
    expected = json.loads((DATA / head / "figures.json").read_text())
    got = figures(policy)
    for key in ("first", "after_failures"):
        torch.testing.assert_close(torch.tensor(got[key]), torch.tensor(expected[key]), atol=1e-5, rtol=1e-4)
    for stage, loss in expected["losses"].items():
        assert got["losses"][stage] == pytest.approx(loss, rel=1e-5), stage


def write_data() -> None:
    """tests/policy/old_layout/ from the code this imports (see the module docstring)."""
    for head, settings in HEADS.items():
        config = CCDPConfig(
            input_features={"observation.state": PolicyFeature(FeatureType.STATE, (STATE_DIM,))},
            output_features={"action": PolicyFeature(FeatureType.ACTION, (ACTION_DIM,))},
            device="cpu",
            failure_feature="action",
            recovery_head=head,
            training_stage="recovery",
            **SIZES,
            **settings,
        )
        policy = CCDPPolicy(config)
        (DATA / head).mkdir(parents=True, exist_ok=True)
        policy.config._save_pretrained(DATA / head)
        policy.model.recovery_trained.fill_(True)
        if hasattr(policy.model.recovery, "guard_trained"):
            policy.model.recovery.guard_trained.fill_(True)
        layout = {
            k: [list(v.shape), str(v.dtype), *([v.tolist()] if v.dtype == torch.bool else [])]
            for k, v in policy.state_dict().items()
        }
        (DATA / head / "weights.json").write_text(json.dumps(layout, indent=0, sort_keys=True))
        policy.load_state_dict(seeded_weights(layout))
        (DATA / head / "figures.json").write_text(json.dumps(figures(policy.eval())))


if __name__ == "__main__":
    write_data()
    sys.exit(0)
