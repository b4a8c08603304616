"""forward() trains the stage the config names; the recovery stage leaves the base network untouched."""

import torch

from fixtures.policy_factory import make_policy


def test_base_stage_trains_the_base_network_only():
    policy = make_policy(history_length=2).train()
    batch = {
        "observation.state": torch.randn(8, 3, 2),
        "action": torch.randn(8, 18, 2).clamp(-1, 1),
        "action_is_pad": torch.zeros(8, 18, dtype=torch.bool),
    }
    loss, _ = policy.forward(batch)
    loss.backward()
    assert all(p.grad is not None for p in policy.model.base.parameters())
    assert all(p.grad is None for p in policy.model.recovery.parameters())
    assert {id(p) for p in policy.get_optim_params()} == {id(p) for p in policy.model.base.parameters()}


def test_recovery_stage_freezes_the_base_and_learns_eps_z():
    torch.manual_seed(0)
    policy = make_policy(training_stage="recovery", failure_feature="final_state").train()
    base_before = {k: v.clone() for k, v in policy.model.base.state_dict().items()}
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=1e-3)
    # Two failure features, each paired with its own chunk: eps_z must learn the pairing.
    chunks = torch.stack([torch.full((16, 2), 0.5), torch.full((16, 2), -0.5)])
    z = torch.tensor([[0.5, 0.5], [-0.5, -0.5]])
    losses = []
    for _ in range(150):
        pick = torch.randint(0, 2, (32,))
        loss, _ = policy.forward({"action": chunks[pick], "observation.failure_feature": z[pick]})
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert bool(policy.model.recovery_trained)
    assert sum(losses[-20:]) / 20 < 0.5 * sum(losses[:20]) / 20
    for key, value in policy.model.base.state_dict().items():
        torch.testing.assert_close(value, base_before[key], msg=key)
    assert all(not p.requires_grad for p in policy.model.base.parameters())


def test_classifier_stage_learns_from_demo_windows_which_chunks_repeat_a_failure_set():
    """recovery_head=classifier reads demonstration windows (as the base does), draws each row's failure set
    from the other rows and learns P(repeat | a_t, s): with two options, told which one failed, it ranks that
    option's noisy chunks above the other's. The base stays frozen."""
    torch.manual_seed(0)
    policy = make_policy(
        training_stage="recovery",
        recovery_head="classifier",
        failure_feature="action",
    ).train()
    assert policy.config.observation_delta_indices == [0] and policy.config.action_delta_indices is not None
    base_before = {k: v.clone() for k, v in policy.model.base.state_dict().items()}
    optimizer = torch.optim.Adam(policy.get_optim_params(), lr=1e-3)
    chunks = torch.stack([torch.full((16, 2), 0.5), torch.full((16, 2), -0.5)])
    for _ in range(200):
        pick = torch.randint(0, 2, (32,))
        loss, _ = policy.forward({"observation.state": torch.zeros(32, 1, 2), "action": chunks[pick]})
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert bool(policy.model.recovery_trained)
    policy.eval()
    with torch.no_grad():
        noisy = policy.model.noise_scheduler.add_noise(
            chunks, torch.randn_like(chunks) * 0.1, torch.tensor([5, 5])
        )
        failed_first = chunks[0].flatten()[None, None].expand(2, 1, 32)  # action z of option 0
        logits = policy.model.recovery(
            noisy, torch.tensor([5, 5]), torch.zeros(2, 2), failed_first, torch.ones(2, 1, dtype=torch.bool)
        )
    assert logits[0] > 2 and logits[1] < -2, logits
    for key, value in policy.model.base.state_dict().items():
        torch.testing.assert_close(value, base_before[key], msg=key)
