"""Composed sampling: analytic denoisers give the known composed distribution; network calls per step do
not grow with the number of failures; failures re-plan only their own row."""

from dataclasses import replace

import pytest
import torch
from torch import nn

from fixtures.policy_factory import make_policy

HORIZON, ACTION_DIM, SPREAD = 16, 2, 0.05


def optimal_eps(scheduler, noisy, timestep, mean):
    """Exact noise estimate for data ~ N(mean, SPREAD^2 I) noised to `timestep`."""
    ab = scheduler.alphas_cumprod[timestep.long()].view(-1, 1, 1)
    return (1 - ab).sqrt() * (noisy - ab.sqrt() * mean) / (ab * SPREAD**2 + 1 - ab)


class GaussianBase(nn.Module):
    """eps_a, eps_s, eps_h of Gaussians with three known means, selected by the keep flags."""

    def __init__(self, scheduler, means):
        super().__init__()
        self.scheduler, self.means = scheduler, means

    def forward(self, noisy, timestep, state, keep_s, history, keep_h):
        which = (keep_s + 2 * keep_h).long().view(-1)  # 0: a, 1: s, 2: h
        return optimal_eps(self.scheduler, noisy, timestep, self.means[which])


class GaussianRecovery(nn.Module):
    """eps_z of a Gaussian centred on the chunk that z encodes (failure_feature=action)."""

    def __init__(self, scheduler):
        super().__init__()
        self.scheduler = scheduler

    def forward(self, noisy, timestep, z, keep_z):
        return optimal_eps(self.scheduler, noisy, timestep, z.view(-1, HORIZON, ACTION_DIM))


def test_sampling_with_analytic_denoisers_reaches_the_composed_mean():
    torch.manual_seed(0)
    policy = make_policy(w_h=0.5, w_z=0.5, clip_sample=False, history_length=2)
    policy.model.weights = replace(policy.model.weights, z_reference="eps_a")  # the paper's literal eq. (4)
    means = torch.rand(3, HORIZON, ACTION_DIM) * 0.6 - 0.3
    policy.model.base = GaussianBase(policy.model.noise_scheduler, means)
    policy.model.recovery = GaussianRecovery(policy.model.noise_scheduler)
    policy.model.recovery_trained.fill_(True)
    rows = 256
    obs = {"observation.state": torch.zeros(rows, 2)}
    policy.predict_action_chunk(obs)
    mu_z = torch.rand(2, HORIZON, ACTION_DIM) * 0.6 - 0.3
    policy.report_failure(list(range(rows // 2)), mu_z[0].flatten().expand(rows // 2, -1))
    policy.report_failure(list(range(rows // 4)), mu_z[1].flatten().expand(rows // 4, -1))
    chunks = policy.predict_action_chunk(obs)

    mu_a, mu_s, mu_h = means
    base = mu_a + 1.0 * (mu_s - mu_a) + 0.5 * (mu_h - mu_a)
    expected = {
        "two failures": (slice(0, rows // 4), base + 0.5 * (mu_z[0] - mu_a) + 0.5 * (mu_z[1] - mu_a)),
        "one failure": (slice(rows // 4, rows // 2), base + 0.5 * (mu_z[0] - mu_a)),
        "no failure": (slice(rows // 2, rows), base),
    }
    steps = slice(0, policy.config.n_action_steps)
    for name, (sel, mean) in expected.items():
        got = chunks[sel].mean(dim=0)
        assert torch.allclose(got, mean[steps], atol=0.03), (
            f"{name}: max error {(got - mean[steps]).abs().max()}"
        )


DEMONSTRATED = torch.tensor([0.4, 0.3, 0.2, 0.1])  # preference over four modes, as on the 2-D task


def mixture_eps(scheduler, noisy, timestep, modes, weights):
    """Exact noise estimate for data ~ sum_k weights[:, k] N(modes[k], SPREAD^2 I) noised to `timestep`."""
    ab = scheduler.alphas_cumprod[timestep.long()].view(-1, 1, 1, 1)
    var = ab * SPREAD**2 + 1 - ab
    offset = ab.sqrt() * modes[None] - noisy[:, None]  # (R, K, horizon, A)
    log_resp = weights.clamp_min(1e-12).log() + (-(offset**2).sum(dim=(2, 3)) / (2 * var.view(-1, 1)))
    score = (log_resp.softmax(dim=1)[..., None, None] * offset / var).sum(dim=1)
    return -(1 - ab.view(-1, 1, 1)).sqrt() * score


class MixtureBase(nn.Module):
    """eps_a = eps_s: the demonstrated mixture, whatever the state."""

    def __init__(self, scheduler, modes):
        super().__init__()
        self.scheduler, self.modes = scheduler, modes

    def forward(self, noisy, timestep, state, keep_s, history, keep_h):
        weights = DEMONSTRATED.expand(noisy.shape[0], -1)
        return mixture_eps(self.scheduler, noisy, timestep, self.modes, weights)


def recovery_shares(z: torch.Tensor) -> torch.Tensor:
    """Mode shares of the recovery set for a failed mode z (one-hot): the demonstrated mixture without it."""
    weights = DEMONSTRATED * (1 - z)
    return weights / weights.sum(-1, keepdim=True)


class MixtureRecovery(nn.Module):
    """eps_z of the recovery sets; with z dropped, of their union (every demonstrated mode serves as a failure
    as often as it is demonstrated, as in recovery synthesis)."""

    def __init__(self, scheduler, modes):
        super().__init__()
        self.scheduler, self.modes = scheduler, modes
        self.null_shares = (DEMONSTRATED[:, None] * recovery_shares(torch.eye(4))).sum(dim=0)

    def forward(self, noisy, timestep, z, keep_z):
        weights = torch.where(keep_z.bool(), recovery_shares(z), self.null_shares)
        return mixture_eps(self.scheduler, noisy, timestep, self.modes, weights)


class MixtureClassifier(nn.Module):
    """logit of the exact posterior probability that a noisy chunk comes from a mode in the failure set."""

    def __init__(self, scheduler, modes):
        super().__init__()
        self.scheduler, self.modes = scheduler, modes

    def forward(self, noisy, timestep, state, z, z_mask):
        ab = self.scheduler.alphas_cumprod[timestep.long()].view(-1, 1)
        offset = ab.sqrt()[..., None, None] * self.modes[None] - noisy[:, None]
        log_joint = DEMONSTRATED.log() - (offset**2).sum(dim=(2, 3)) / (2 * (ab * SPREAD**2 + 1 - ab))
        failed = (z * z_mask[..., None]).amax(dim=1).bool()
        inside = log_joint.masked_fill(~failed, float("-inf")).logsumexp(dim=1)
        return inside - log_joint.masked_fill(failed, float("-inf")).logsumexp(dim=1)


def mixture_policy(**overrides):
    """A policy whose networks are the exact noise estimates of the four-mode mixture, and those modes."""
    torch.manual_seed(0)
    policy = make_policy(failure_feature="primitive", num_primitives=4, clip_sample=False, **overrides)
    modes = torch.randn(4, HORIZON, ACTION_DIM)
    modes = 0.3 * modes / modes.pow(2).mean(dim=(1, 2), keepdim=True).sqrt()  # RMS 0.3, ~2.4 apart
    policy.model.base = MixtureBase(policy.model.noise_scheduler, modes)
    recovery = MixtureClassifier if policy.config.recovery_head == "classifier" else MixtureRecovery
    policy.model.recovery = recovery(policy.model.noise_scheduler, modes)
    policy.model.recovery_trained.fill_(True)
    return policy, modes


def mode_shares(policy, modes, failed: list[int], rows: int = 1024) -> torch.Tensor:
    """Share of each mode among `rows` chunks planned after the modes `failed` were reported, in that
    order."""
    obs = {"observation.state": torch.zeros(rows, 2)}
    policy.reset()
    policy.predict_action_chunk(obs)
    for mode in failed:
        policy.report_failure(z=policy.model.feature.one_hot(torch.full((rows,), mode)))
    chunks = policy.predict_action_chunk(obs)  # (rows, n_action_steps, A): the chunk's first steps
    steps = chunks.shape[1]
    nearest = ((chunks[:, None] - modes[None, :, :steps]) ** 2).sum(dim=(2, 3)).argmin(dim=1)
    return torch.bincount(nearest, minlength=4).float() / rows


def test_classifier_guidance_of_exact_mixtures_samples_everything_but_what_failed_in_proportion():
    """With the exact noisy-chunk classifier, guidance (under LeRobot's inference mode) draws the remaining
    modes in their demonstrated proportions after one and after two failures, unlike the per-failure sums of
    eq. (4) below, asking about each distinct failure (a repeated failure counts once); in a batch where only
    some rows failed, the others keep the base's shares."""
    policy, modes = mixture_policy(recovery_head="classifier")
    torch.manual_seed(1)
    for failed in ([0], [0, 1], [2], [1, 3, 1]):
        expected = DEMONSTRATED.clone()
        expected[failed] = 0
        expected /= expected.sum()
        with torch.inference_mode():
            got = mode_shares(policy, modes, failed)
        print("classifier guidance after", failed, [round(x, 3) for x in got.tolist()])
        assert (got - expected).abs().max() < 0.05, f"after {failed}: {got.tolist()} vs {expected.tolist()}"
    rows = 2048
    obs = {"observation.state": torch.zeros(rows, 2)}
    policy.reset()
    policy.predict_action_chunk(obs)
    policy.report_failure(rows=list(range(rows // 2)), z=policy.model.feature.one_hot(torch.zeros(rows // 2)))
    chunks = policy.predict_action_chunk(obs)
    nearest = ((chunks[:, None] - modes[None, :, : chunks.shape[1]]) ** 2).sum(dim=(2, 3)).argmin(dim=1)
    failed_rows, fresh_rows = (
        torch.bincount(part, minlength=4) / (rows // 2) for part in nearest.split(rows // 2)
    )
    assert failed_rows[0] < 0.02 and (fresh_rows - DEMONSTRATED).abs().max() < 0.05, (failed_rows, fresh_rows)


@pytest.mark.parametrize("w_z", [1.0, 3.0])
@pytest.mark.parametrize("z_reference", ["eps_a", "eps_z_null"])
def test_composed_sampling_of_exact_mixtures_avoids_failed_modes_and_keeps_the_preference_order(
    z_reference, w_z
):
    """With exact noise estimates, what is left is the sampler's own error: eq. (4) is the score of a product
    only at zero noise. The shares are printed (`pytest -s -k exact_mixtures`): the exact answer after mode 0
    failed is 0 / 0.50 / 0.33 / 0.17; only the paper's form at w_z = 1 gives it (eps_z_null over-weights the
    most preferred remaining mode, more so at w_z = 3), which the order asserted here does not see. The
    policy measures against eps_z_null; eps_a is eq. (4) as the paper writes it (`CompositionWeights`)."""
    policy, modes = mixture_policy(w_z=w_z)
    policy.model.weights = replace(policy.model.weights, z_reference=z_reference)

    def shares(failed: list[int]) -> torch.Tensor:
        return mode_shares(policy, modes, failed)

    dp, one, two = shares([]), shares([0]), shares([0, 1])
    rounded = [[round(x, 2) for x in shares.tolist()] for shares in (dp, one, two)]
    report = (
        f"{z_reference} w_z={w_z}: no failure {rounded[0]}, after mode 0 {rounded[1]}, "
        f"after modes 0 and 1 {rounded[2]}"
    )
    print(report)
    assert (dp - DEMONSTRATED).abs().max() < 0.05, report
    assert one[0] < 0.02 and one[1] > one[2] > one[3], report
    assert two[0] + two[1] < 0.2 and two[2] > two[3], report


@pytest.mark.parametrize(
    "mode, head",
    [
        ("ccdp", {}),
        ("dp", {}),
        ("ccdp", {"recovery_head": "classifier"}),
        ("ccdp", {"recovery_head": "set_denoiser"}),
    ],
)
def test_network_calls_per_step_do_not_grow_with_failures(mode, head):
    policy = make_policy(recovery_mode=mode, w_h=0.5, history_length=2, **head)
    policy.model.recovery_trained.fill_(True)
    if head.get("recovery_head") == "set_denoiser":
        policy.model.recovery.guard_trained.fill_(True)  # its default guarded steps
    calls = {"base": 0, "recovery": 0}
    policy.model.base.register_forward_hook(lambda *_: calls.__setitem__("base", calls["base"] + 1))
    policy.model.recovery.register_forward_hook(
        lambda *_: calls.__setitem__("recovery", calls["recovery"] + 1)
    )
    obs = {"observation.state": torch.zeros(2, 2)}
    steps = policy.config.num_inference_steps
    counts = {}
    for n in (0, 1, 2, 4, 8):
        policy.reset()
        policy.predict_action_chunk(obs)
        for _ in range(n):
            policy.report_failure()
        calls.update(base=0, recovery=0)
        policy.predict_action_chunk(obs)
        counts[n] = (calls["base"], calls["recovery"])
    assert all(base == steps for base, _ in counts.values()), counts
    if mode == "ccdp":
        assert counts[0][1] == 0 and all(counts[n][1] == steps for n in (1, 2, 4, 8)), counts
    else:
        assert all(rec == 0 for _, rec in counts.values()), counts


def test_failure_flag_replans_only_the_failed_row_and_reset_forgets():
    torch.manual_seed(0)
    policy = make_policy(n_action_steps=8)
    obs = {"observation.state": torch.randn(3, 2)}
    first = [policy.select_action(obs) for _ in range(3)]
    assert policy._rollout.memory.plan_pos.tolist() == [3, 3, 3]
    plan_before = policy._rollout.memory.plan.clone()
    flagged = {**obs, "observation.failure": torch.tensor([[0.0], [1.0], [0.0]])}
    action = policy.select_action(flagged)
    assert policy.failure_count().tolist() == [0, 1, 0]
    assert policy._rollout.memory.plan_pos.tolist() == [4, 1, 4]  # row 1 started a fresh chunk
    torch.testing.assert_close(action[[0, 2]], plan_before[[0, 2], 3])
    assert not torch.equal(policy._rollout.memory.plan[1], plan_before[1])
    # The failed row restarted its windows at the current frame, as at an episode start.
    torch.testing.assert_close(
        policy._rollout.memory.frames[1],
        obs["observation.state"][1].expand_as(policy._rollout.memory.frames[1]),
    )
    assert len(first) == 3
    policy.reset()
    policy.select_action(obs)
    assert policy.failure_count().tolist() == [0, 0, 0]


def test_failure_feature_of_a_flagged_failure_is_the_state_before_it():
    """With `failure_state_at="attempt_end"` a failure's z is the state where the attempt stopped."""
    policy = make_policy(
        failure_feature="final_state", failure_state_dims=[1], failure_state_at="attempt_end"
    )
    before = torch.tensor([[0.1, 0.7], [0.2, -0.4]])
    policy.select_action({"observation.state": before})
    policy.select_action(
        {"observation.state": torch.zeros(2, 2), "observation.failure": torch.tensor([[1.0], [1.0]])}
    )
    z, mask = policy._rollout.failures.padded()
    assert mask.all() and z[:, 0, 0].tolist() == pytest.approx([0.7, -0.4])


def test_demonstrated_end_z_is_where_the_followed_demonstration_ended_not_where_the_attempt_stopped(
    monkeypatch,
):
    """A pick that slips mid-lift stops far from where any pick is demonstrated to end; with
    `failure_state_at="demonstrated_end"` its z is the end of the demonstration whose chunk it was
    executing."""
    policy = make_policy(
        failure_feature="final_state",
        failure_state_dims=[1],
        n_action_steps=2,
        failure_state_at="demonstrated_end",
    )
    towards = torch.stack([torch.full((HORIZON, ACTION_DIM), -1.0), torch.full((HORIZON, ACTION_DIM), 1.0)])
    policy.model.outcomes.fill(towards, torch.tensor([[-0.8], [0.6]]), torch.tensor([0, 0]))
    # the last one after the failure
    planned = iter([towards[:1] * 0.9, towards[1:] * 0.9, towards[:1] * 0.9])
    monkeypatch.setattr(policy, "_sample", lambda rows, noise: next(planned))
    obs = {"observation.state": torch.tensor([[0.0, 0.3]])}
    for _ in range(3):  # plans the first chunk, executes it, then re-plans towards the second demonstration
        policy.select_action(obs)
    policy.select_action({**obs, "observation.failure": torch.tensor([[1.0]])})
    z, mask = policy._rollout.failures.padded()
    assert mask.all() and z[0, 0].tolist() == pytest.approx([0.6])


@pytest.mark.parametrize("feature", ["primitive", "action"])
def test_flagged_failure_takes_its_label_from_the_latest_chunk_and_its_action_z_from_the_first(
    monkeypatch, feature
):
    """An attempt whose first chunk heads to option 0 and whose re-planned chunk reaches option 1 failed at
    option 1: `primitive` z names option 1, while `action` z stays the chunk that chose the option."""
    policy = make_policy(
        failure_feature=feature, primitive_key="primitive", num_primitives=2, n_action_steps=2
    )
    towards = torch.stack([torch.full((HORIZON, ACTION_DIM), -1.0), torch.full((HORIZON, ACTION_DIM), 1.0)])
    policy.model.outcomes.fill(towards, torch.zeros(2, 1), torch.tensor([0, 1]))
    planned = iter([towards[:1] * 0.9, towards[1:] * 0.9])
    monkeypatch.setattr(policy, "_sample", lambda rows, noise: next(planned))
    obs = {"observation.state": torch.zeros(1, 2)}
    for _ in range(3):  # plans the first chunk, executes it, then re-plans
        policy.select_action(obs)
    policy.report_failure()
    z, mask = policy._rollout.failures.padded()
    expected = (
        policy.model.feature.one_hot(torch.tensor([1]))
        if feature == "primitive"
        else towards[0].flatten()[None] * 0.9
    )
    assert mask.all()
    torch.testing.assert_close(z[:, 0], expected)


def test_attempt_end_label_names_the_option_ending_where_the_attempt_stopped(monkeypatch):
    """The Bartender's chunk that pours into cup 0 and goes on to an unavailable cup 1 fails there, still
    looked up as option 0: with `failure_label_at="attempt_end"` the failure is named for the option whose
    demonstrated end is nearest the state where it stopped (option 1), with the latest chunk's (option 0)
    under the default."""
    labels = {}
    for label_at in ("latest_chunk", "attempt_end"):
        policy = make_policy(
            failure_feature="primitive",
            primitive_key="primitive",
            num_primitives=2,
            failure_state_dims=[1],
            failure_label_at=label_at,
        )
        towards = torch.stack(
            [torch.full((HORIZON, ACTION_DIM), -1.0), torch.full((HORIZON, ACTION_DIM), 1.0)]
        )
        policy.model.outcomes.fill(towards, torch.tensor([[-0.8], [0.6]]), torch.tensor([0, 1]))
        monkeypatch.setattr(policy, "_sample", lambda rows, noise, chunk=towards[:1] * 0.9: chunk)
        policy.select_action({"observation.state": torch.tensor([[0.0, 0.5]])})  # stops near option 1's end
        flagged = torch.tensor([[0.0, -0.5]])  # the restart's frame, near option 0's end: not read
        policy.select_action({"observation.state": flagged, "observation.failure": torch.tensor([[1.0]])})
        z, mask = policy._rollout.failures.padded()
        assert mask.all()
        labels[label_at] = int(z[0, 0].argmax())
    assert labels == {"latest_chunk": 0, "attempt_end": 1}


def test_untrained_recovery_head_falls_back_to_dp_with_a_warning(caplog):
    policy = make_policy()
    obs = {"observation.state": torch.zeros(1, 2)}
    policy.select_action(obs)
    policy.report_failure()
    with caplog.at_level("WARNING"):
        policy.select_action(obs)
    assert "untrained" in caplog.text
