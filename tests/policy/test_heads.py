"""A recovery head is one module under policy/heads/: `recovery_head` names a registered head, or none, and
then the policy names the default for its inputs (the set denoiser where it runs, else `unet`) in the
checkpoint it saves; the model asks the head for its loss and its estimate and never compares the name
itself, and a head's own settings are refused with another head."""

import ast
import json
from pathlib import Path

import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.factory import make_policy as lerobot_make_policy
from torch import Tensor, nn

import lerobot_ccdp
from lerobot_ccdp.envs import CCDPEnvConfig
from lerobot_ccdp.policy.configuration_ccdp import RECOVERY_HEADS, CCDPConfig
from lerobot_ccdp.policy.heads import HEADS, RecoveryHead
from lerobot_ccdp.policy.heads.registry import Estimate
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

from fixtures.policy_factory import make_policy

PACKAGE = Path(lerobot_ccdp.__file__).parent


def test_the_configs_choices_are_the_registered_heads():
    """The Literal stays in the config (draccus and --help list it); it must name exactly the heads."""
    assert set(RECOVERY_HEADS) == set(HEADS)
    assert all(HEADS[name].name == name for name in HEADS)


def name_comparisons(path: Path) -> list[int]:
    """Lines comparing `recovery_head` (an attribute, a key or a call) with anything; asking the head
    (`head_class(...).training_data == ...`) is no comparison of its name."""
    lines = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Compare):
            sides = [ast.unparse(side) for side in (node.left, *node.comparators)]
            if any("recovery_head" in side and not side.startswith("head_class(") for side in sides):
                lines.append(node.lineno)
    return lines


def test_no_module_outside_the_heads_compares_the_head_name():
    found = {
        str(path.relative_to(PACKAGE)): lines
        for path in PACKAGE.rglob("*.py")
        if "heads" not in path.parts and (lines := name_comparisons(path))
    }
    assert found == {}, "ask the head (`heads.head_class(name)`) instead of comparing its name"


class CountingHead(RecoveryHead):
    """A head written outside the package: its estimate is eq. (4) without failure terms, its loss a constant;
    it counts its calls."""

    name = "counting"
    network = staticmethod(lambda config: nn.Linear(1, 1))
    training_data = "recovery_pairs"

    def __init__(self):
        self.estimates, self.losses = [], 0

    def loss(self, model, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        self.losses += 1
        return torch.tensor(7.0), {"counted": True}

    def estimate(self, model, weights, state, history, z, z_mask, timesteps) -> Estimate:
        self.estimates.append(z_mask.sum(dim=1).tolist())
        return model.estimate_without_failures(weights, state, history)


def test_the_model_hands_a_rows_failures_and_the_recovery_loss_to_its_head():
    policy = make_policy(failure_feature="action")
    head = policy.model.head = CountingHead()
    policy.model.recovery_trained.fill_(True)
    batch = {"observation.state": torch.zeros(3, 2)}
    policy.select_action(batch)
    assert head.estimates == []  # no failure yet: the model's own composition
    policy.report_failure(rows=[1])
    policy.select_action(batch)
    assert head.estimates == [[1]]  # only row 1 re-planned, with its one failure
    policy.config.training_stage = "recovery"
    loss, info = policy.model.compute_loss({})
    assert (loss.item(), info, head.losses) == (7.0, {"counted": True}, 1)


@pytest.mark.parametrize(
    "setting", [{"failure_guard_steps": 0}, {"w_z_steps": None}, {"stratum_weights": False}]
)
@pytest.mark.parametrize("head", ["unet", "classifier"])
def test_a_setting_of_another_head_turned_off_sets_nothing(head, setting):
    """A config.json saved when the set denoiser's guard or window defaulted to off holds that for every head:
    it loads."""
    config = CCDPConfig(recovery_head=head, device="cpu", **setting)
    assert getattr(config, *setting) == next(iter(setting.values()))


@pytest.mark.parametrize("setting", [{"failure_guard_steps": 2}, {"w_z_steps": 5}, {"stratum_weights": True}])
@pytest.mark.parametrize("head", ["unet", "classifier"])
def test_a_setting_of_another_head_is_refused_naming_the_head_that_reads_it(head, setting):
    (field,) = setting
    with pytest.raises(
        ValueError, match=f"`{field}` .* of the 'set_denoiser' head.*recovery_head=set_denoiser"
    ):
        CCDPConfig(recovery_head=head, device="cpu", **setting)


def made_by_lerobot(obs_type: str = "state", **settings) -> CCDPPolicy:
    """A fresh policy from LeRobot's `make_policy`, which sets the config's features from a ccdp env's, as
    lerobot-eval does (lerobot-train sets them from a dataset's the same way) before the policy validates
    them."""
    env = CCDPEnvConfig(
        task="DoorOpening-lite-v0", obs_type=obs_type, observation_width=48, observation_height=48
    )
    return lerobot_make_policy(CCDPConfig(device="cpu", **settings), env_cfg=env)


@pytest.mark.parametrize(
    ("obs_type", "n_obs_steps", "head"),
    [("state", 1, "set_denoiser"), ("pixels_agent_pos", 1, "unet"), ("state", 2, "unet")],
    ids=["state", "cameras", "two_observation_steps"],
)
def test_the_default_head_is_the_set_denoiser_where_it_runs_and_unet_elsewhere(obs_type, n_obs_steps, head):
    assert CCDPConfig(device="cpu").recovery_head == "auto"  # named once the features are known
    policy = made_by_lerobot(obs_type, n_obs_steps=n_obs_steps)
    assert policy.config.recovery_head == head and policy.model.head.name == head


@pytest.mark.parametrize("head", ["unet", "classifier"])
def test_a_named_head_wins_over_the_default(head):
    assert made_by_lerobot(recovery_head=head).model.head.name == head


def test_a_named_set_denoiser_with_cameras_is_refused_with_the_fix():
    with pytest.raises(
        ValueError, match="no camera images yet: use --policy.recovery_head=unet with cameras"
    ):
        made_by_lerobot("pixels_agent_pos", recovery_head="set_denoiser")


def test_a_setting_of_the_set_denoiser_with_cameras_names_the_head_the_default_chose():
    """The fix is to remove the flag: the set denoiser that reads it cannot serve cameras, so the message
    says why rather than suggesting it."""
    with pytest.raises(ValueError, match="`failure_guard_steps` .* the 'unet' head reads none") as refused:
        made_by_lerobot("pixels_agent_pos", failure_guard_steps=2)
    message = str(refused.value)
    assert "Remove --policy.failure_guard_steps (the 'set_denoiser' head cannot serve" in message
    assert "use --policy.recovery_head=set_denoiser" not in message


def test_a_checkpoint_holds_the_default_head_it_was_built_with(tmp_path):
    """What lerobot-ccdp-synthesize, the recovery stage and lerobot-eval read: config.json names the head."""
    made_by_lerobot().save_pretrained(tmp_path)
    assert json.loads((tmp_path / "config.json").read_text())["recovery_head"] == "set_denoiser"
    assert PreTrainedConfig.from_pretrained(tmp_path).recovery_head == "set_denoiser"
    loaded = CCDPPolicy.from_pretrained(tmp_path)
    assert loaded.config.recovery_head == loaded.model.head.name == "set_denoiser"
