"""A recovery head is one module under policy/heads/: `recovery_head` names a registered head, the model asks
the head for its loss and its estimate and never compares the name itself, and a head's own settings are
refused with another head."""

import ast
from pathlib import Path

import pytest
import torch
from torch import Tensor, nn

import lerobot_ccdp
from lerobot_ccdp.policy.configuration_ccdp import RECOVERY_HEADS, CCDPConfig
from lerobot_ccdp.policy.heads import HEADS, RecoveryHead
from lerobot_ccdp.policy.heads.registry import Estimate

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


@pytest.mark.parametrize("setting", [{"failure_guard_steps": 2}, {"w_z_steps": 5}, {"stratum_weights": True}])
@pytest.mark.parametrize("head", ["unet", "classifier"])
def test_a_setting_of_another_head_is_refused_naming_the_head_that_reads_it(head, setting):
    (field,) = setting
    with pytest.raises(
        ValueError, match=f"`{field}` .* of the 'set_denoiser' head.*recovery_head=set_denoiser"
    ):
        CCDPConfig(recovery_head=head, device="cpu", **setting)
