"""report_failure() from a robot's failure detector, whatever grad mode the loop's select_action ran in:
lerobot-eval and lerobot-record act under torch.inference_mode(), custom loops often under torch.no_grad()."""

import contextlib

import pytest
import torch

from lerobot_ccdp.policy.rollout_memory import MAX_FAILURES

from fixtures.policy_factory import make_policy

MODES = {"inference_mode": torch.inference_mode, "no_grad": torch.no_grad, "grad": contextlib.nullcontext}


def recovery_z_seen(policy) -> list[torch.Tensor]:
    """Record the z rows every recovery call receives (the failures eq. (4) composes)."""
    seen = []
    policy.model.recovery.register_forward_hook(lambda _m, args, _out: seen.append(args[2].clone()))
    return seen


@pytest.mark.parametrize("acting", ["inference_mode", "no_grad"])
def test_failure_reported_outside_the_acting_mode_changes_the_next_plan(acting):
    policy = make_policy(n_action_steps=8)
    policy.model.recovery_trained.fill_(True)
    seen = recovery_z_seen(policy)
    obs = {"observation.state": torch.randn(2, 2)}
    z_f = torch.tensor([[0.5] * policy.config.failure_feature_dim])
    with MODES[acting]():
        policy.select_action(obs)
        policy.select_action(obs)
    assert not seen, "no failure yet: eps_z is not evaluated"
    policy.report_failure(rows=[1], z=z_f)  # a detector's callback, outside the loop's mode
    assert policy.failure_count().tolist() == [0, 1]
    with MODES[acting]():
        policy.select_action(obs)
    assert policy._rollout.memory.plan_pos.tolist() == [3, 1], "row 1 re-planned, row 0 kept its chunk"
    assert seen, "the re-plan composed eps_z of the reported failure"
    torch.testing.assert_close(seen[0][0], z_f[0])


@pytest.mark.parametrize("acting", ["inference_mode", "no_grad"])
def test_failure_buffer_stays_bounded_when_reporting_outside_the_acting_mode(acting):
    policy = make_policy()
    obs = {"observation.state": torch.zeros(1, 2)}
    for _ in range(MAX_FAILURES + 4):
        with MODES[acting]():
            policy.select_action(obs)
        policy.report_failure()
    assert policy.failure_count().tolist() == [MAX_FAILURES]
    assert policy._rollout.failures.z.shape[1] == MAX_FAILURES


def test_switching_modes_between_steps_keeps_acting():
    """A rollout started under inference_mode can go on under no_grad (and back) without a reset, and a
    failure reported inside the loop's own mode is remembered too."""
    policy = make_policy(n_action_steps=2)
    obs = {"observation.state": torch.zeros(1, 2)}
    for mode in ["inference_mode", "no_grad", "inference_mode", "grad"]:
        with MODES[mode]():
            policy.select_action(obs)
            policy.select_action({**obs, "observation.failure": torch.ones(1, 1)})
            policy.select_action(obs)
            policy.report_failure()
    assert policy.failure_count().tolist() == [8]


def test_bad_rows_or_z_name_the_expected_shape():
    policy = make_policy()
    policy.select_action({"observation.state": torch.zeros(2, 2)})
    with pytest.raises(ValueError, match=r"acts on 2 row\(s\), indices 0..1"):
        policy.report_failure(rows=[2])
    with pytest.raises(ValueError, match=r"got shape \(2, 3\).*\(1, 32\)"):
        policy.report_failure(rows=[0], z=torch.zeros(2, 3))
    assert policy.failure_count().tolist() == [0, 0]
