"""Devices: a checkpoint saved from CUDA loads and is synthesised from on a CPU-only machine; --policy.device
picks the synthesis device and names the fix when this machine lacks it. Nothing here needs a GPU."""

import json
from pathlib import Path

import pytest
import torch
import yaml
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.processor import PolicyProcessorPipeline
from lerobot.processor.converters import policy_action_to_transition, transition_to_policy_action

from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.recovery import synthesize
from lerobot_ccdp.recovery.synthesize import synthesis_device

from fixtures.policy_factory import untrained_checkpoint
from fixtures.reaching import REACHING_REPO_ID

SETTINGS = {"failure_feature": "primitive", "num_primitives": 4}
SMALL = {
    "n_states": 8,
    "chunks_per_state": 4,
    "batch_states": 8,
    "pairs_per_failure": 2,
    "demo_frames": 100,
    "delta_x": 0.05,
    "delta_z": 0.1,
}
PREPROCESSOR = "policy_preprocessor.json"
# where a checkpoint saved from CUDA runs on this machine
HERE = "cuda" if torch.cuda.is_available() else "cpu"


@pytest.fixture(scope="module")
def cuda_checkpoint(reaching_root, tmp_path_factory) -> Path:
    """An untrained base checkpoint as lerobot-train saves it on a GPU: config and preprocessor say cuda."""
    checkpoint = untrained_checkpoint(
        reaching_root, tmp_path_factory.mktemp("cuda_base") / "pretrained_model", **SETTINGS
    )
    config = json.loads((checkpoint / "config.json").read_text())
    (checkpoint / "config.json").write_text(json.dumps({**config, "device": "cuda"}))
    pre = json.loads((checkpoint / PREPROCESSOR).read_text())
    for step in pre["steps"]:
        if step["registry_name"] == "device_processor":
            step["config"]["device"] = "cuda"
    (checkpoint / PREPROCESSOR).write_text(json.dumps(pre))
    return checkpoint


def synthesize_cli(checkpoint: Path, demos: Path, out: Path, *device: str) -> LeRobotDataset:
    out.parent.mkdir(parents=True)
    recipe = out.parent / "recipe.yaml"
    recipe.write_text(yaml.safe_dump({"recovery": SMALL}))
    synthesize.main(
        [
            f"--config_path={recipe}",
            f"--dataset.repo_id={REACHING_REPO_ID}",
            f"--dataset.root={demos}",
            f"--policy.path={checkpoint}",
            "--output.repo_id=local/recovery",
            f"--output.root={out}",
            *device,
        ]
    )
    return LeRobotDataset("local/recovery", root=out)


def test_a_checkpoint_saved_from_cuda_loads_where_this_machine_runs_it(cuda_checkpoint):
    policy = CCDPPolicy.from_pretrained(cuda_checkpoint)
    assert policy.config.device == HERE
    assert {p.device.type for p in policy.state_dict().values()} == {HERE}


def test_a_cuda_checkpoint_acts_in_a_loop_that_loads_its_processors_like_lerobot(cuda_checkpoint):
    """LeRobot's loops load the processors with the policy's device as an override; a custom loop does the
    same."""
    policy = CCDPPolicy.from_pretrained(cuda_checkpoint)
    device = {"device_processor": {"device": policy.config.device}}
    pre = PolicyProcessorPipeline.from_pretrained(
        cuda_checkpoint, config_filename=PREPROCESSOR, overrides=device
    )
    post = PolicyProcessorPipeline.from_pretrained(
        cuda_checkpoint,
        config_filename="policy_postprocessor.json",
        to_transition=policy_action_to_transition,
        to_output=transition_to_policy_action,
    )
    with torch.inference_mode():
        action = post(policy.select_action(pre({"observation.state": torch.zeros(1, 2)})))
    assert action.shape == (1, 2) and action.device.type == "cpu"


def test_synthesis_from_a_cuda_checkpoint_follows_it_or_takes_device(
    cuda_checkpoint, reaching_root, tmp_path
):
    followed = synthesize_cli(cuda_checkpoint, reaching_root, tmp_path / "followed" / "out")
    on_cpu = synthesize_cli(cuda_checkpoint, reaching_root, tmp_path / "cpu" / "out", "--policy.device=cpu")
    assert followed.num_frames > 0 and on_cpu.num_frames > 0
    if HERE == "cpu":  # the same device and seed: the same dataset
        actions = [d.hf_dataset.with_format("torch")["action"] for d in (followed, on_cpu)]
        torch.testing.assert_close(*actions)


def test_load_checkpoint_puts_the_policy_on_the_chosen_device(cuda_checkpoint):
    policy, _ = synthesize.load_checkpoint(cuda_checkpoint, "cpu")
    assert policy.config.device == "cpu" and {p.device.type for p in policy.parameters()} == {"cpu"}
    assert synthesize.load_checkpoint(cuda_checkpoint)[0].config.device == HERE


def test_synthesis_device_choice():
    assert synthesis_device("cpu", None) == "cpu"
    assert synthesis_device(None, None) == "cpu"
    assert synthesis_device("cuda", None) == HERE
    assert synthesis_device("cuda", "cpu") == "cpu"
    with pytest.raises(ValueError, match="--policy.device=tpu is not available.*--policy.device=cpu"):
        synthesis_device("cpu", "tpu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="--policy.device=cuda is not available.*leave it out"):
            synthesis_device("cpu", "cuda")
