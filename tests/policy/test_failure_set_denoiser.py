"""recovery_head=set_denoiser: eps_{s,F} starts as the base's eps_s, trains only on rows whose outcome lies
outside their drawn failure set, costs one network call per reverse step for a row with failures, and refuses
the settings it cannot serve."""

import json

import pytest
import torch
from torch import Tensor

from lerobot_ccdp.policy.configuration_ccdp import SIBLING_COUNT_KEY, SIBLING_FEATURES_KEY, CCDPConfig
from lerobot_ccdp.policy.failure_buffer import draw_failure_sets, draw_state_failure_sets, stratum_weights

from fixtures.policy_factory import make_policy

SETTINGS = {
    "failure_feature": "primitive",
    "num_primitives": 3,
    "recovery_head": "set_denoiser",
    "history_length": 0,
}


def test_start_from_copies_the_base_so_the_head_begins_as_eps_s_whatever_the_failures():
    torch.manual_seed(0)
    policy = make_policy(**SETTINGS)
    noisy, step, state = torch.randn(5, 16, 2), torch.randint(0, 100, (5,)), torch.randn(5, 2)
    z, z_mask = (
        torch.eye(3)[torch.randint(0, 3, (5, 2))],
        torch.tensor([[True, False]] * 3 + [[True, True]] * 2),
    )
    ones, no_history = torch.ones(5, 1), torch.zeros(5, 0)
    eps_s = policy.model.base(noisy, step, state, ones, no_history, 0 * ones)
    assert not torch.allclose(policy.model.recovery(noisy, step, state, z, z_mask), eps_s, atol=1e-3)
    policy.model.recovery.start_from(policy.model.base)
    torch.testing.assert_close(policy.model.recovery(noisy, step, state, z, z_mask), eps_s)


def test_failure_sets_come_from_other_rows_and_flag_the_rows_whose_outcome_they_hold():
    torch.manual_seed(0)
    z = torch.eye(4)[torch.arange(64) % 4]
    z_set, z_mask, repeats = draw_failure_sets(z, 3, delta_z=0.1)
    assert z_set.shape == (64, 3, 4) and z_mask[:, 0].all() and not z_mask.all()
    holds_own = ((z_set == z[:, None]).all(-1) & z_mask).any(1)
    assert torch.equal(repeats, holds_own) and 0 < repeats.float().mean() < 1


def test_failure_sets_drawn_at_the_state_keep_the_base_outside_them_in_its_proportions():
    """Each row's own outcome is one of its siblings, the others the base's independent draws (options 0, 1,
    2 at 0.7, 0.2, 0.1): among the rows kept with F = {0} the options left keep the base's 2 : 1, within 0.03
    of the exact 0.67 (about 1000 such rows; the sampling spread is 0.015). A row without siblings draws its
    failures from the other rows, and share 0 draws as `draw_failure_sets` does."""
    torch.manual_seed(0)
    b, k = 20000, 16
    siblings = torch.multinomial(torch.tensor([0.7, 0.2, 0.1]), b * k, replacement=True).float().view(b, k, 1)
    own, count = siblings[:, 0], torch.full((b,), k)
    count[:100] = 0
    z_set, z_mask, repeats = draw_state_failure_sets(own, siblings, count, 3, delta_z=0.25, share=1.0)
    in_siblings = ((z_set[..., None, :] == siblings[:, None]).all(-1).any(-1) | ~z_mask).all(-1)
    assert in_siblings[100:].all() and not in_siblings[:100].all()
    only_zero = ((z_set[..., 0] == 0) | ~z_mask).all(-1)
    left = own[~repeats & only_zero, 0]
    assert len(left) > 500 and (left == 1).float().mean().item() == pytest.approx(2 / 3, abs=0.03)
    torch.manual_seed(1)
    plain = draw_failure_sets(own, 3, delta_z=0.25)
    torch.manual_seed(1)
    drawn = draw_state_failure_sets(own, siblings, count, 3, 0.25, share=0.0)
    for got, expected in zip(drawn, plain, strict=True):
        assert torch.equal(got, expected)


def test_the_loss_leaves_out_rows_whose_own_outcome_is_in_their_failure_set():
    """With a single option, every drawn failure set holds each row's own outcome: no row is kept, so no
    gradient."""
    torch.manual_seed(0)
    policy = make_policy(**{**SETTINGS, "training_stage": "recovery"}).train()
    policy.model.outcomes.fill(torch.zeros(4, 16 * 2), torch.zeros(4, 2), torch.zeros(4, dtype=torch.long))
    batch = {"observation.state": torch.randn(8, 2), "action": torch.randn(8, 16, 2)}  # synthesised rows
    loss, info = policy.forward(batch)
    assert info["kept_rows"] == 0.0 and loss.item() == pytest.approx(info["guard_loss"])  # the guard's alone
    assert bool(policy.model.recovery_trained)  # the first step copied the base into the head


def test_the_guard_learns_from_every_row_beside_the_set_denoiser():
    """The guard's loss is the classifier's on the same rows and failure sets, kept or not: with one option
    every row repeats its failure set, so its loss alone moves the guard, which is then marked trained."""
    torch.manual_seed(0)
    policy = make_policy(**{**SETTINGS, "training_stage": "recovery"}).train()
    policy.model.outcomes.fill(torch.zeros(4, 16 * 2), torch.zeros(4, 2), torch.zeros(4, dtype=torch.long))
    assert not bool(policy.model.recovery.guard_trained)
    loss, info = policy.forward({"observation.state": torch.randn(8, 2), "action": torch.randn(8, 16, 2)})
    loss.backward()
    assert info["guard_loss"] > 0 and bool(policy.model.recovery.guard_trained)
    assert policy.model.recovery.guard.logit.weight.grad.abs().sum() > 0


def test_stratum_weights_give_each_state_and_failure_set_the_weight_of_its_set_alone():
    """1 / (1 - p_s(F)), p_s(F) the share of a row's siblings (the chunks sampled at its state) inside F; the
    padding beyond a row's sibling count is not a sibling, and a row without siblings weighs 1."""
    e = torch.eye(3)
    siblings = torch.stack([e[[0, 0, 0, 1]], e[[0, 0, 0, 1]], e[[1, 2, 0, 0]], torch.zeros(4, 3)])
    count = torch.tensor([4, 4, 2, 0])
    z_set = torch.stack([e[[0, 2]], e[[0, 2]], e[[1, 0]], e[[0, 0]]])
    z_mask = torch.tensor([[True, False], [True, True], [False, True], [True, True]])
    # F = {0}: 3 of 4 in F; F = {0, 2}: the same; F = {0} with 2 real siblings (1, 2): none; no siblings
    weights = stratum_weights(z_set, z_mask, siblings, count, delta_z=0.5)
    torch.testing.assert_close(weights, torch.tensor([4.0, 4, 1, 1]))


def test_stratum_weights_change_the_loss_only_where_a_failure_set_covers_some_of_the_base():
    """The same draws with and without `stratum_weights`: equal when every sibling lies outside every failure
    set (weight 1), different when the siblings share the rows' outcomes; a dataset without siblings is
    refused with the fix."""
    policy = make_policy(**{**SETTINGS, "training_stage": "recovery", "stratum_weights": True}).train()
    policy.model.outcomes.fill(torch.randn(3, 16 * 2), torch.zeros(3, 2), torch.arange(3))
    rows = {"observation.state": torch.randn(32, 2), "action": torch.randn(32, 16, 2)}

    def loss(weighted: bool, siblings: Tensor) -> float:
        policy.config.stratum_weights = weighted
        torch.manual_seed(0)
        batch = {**rows, SIBLING_FEATURES_KEY: siblings, SIBLING_COUNT_KEY: torch.full((32, 1), 4)}
        return policy.forward(batch)[0].item()

    outside = torch.zeros(32, 4, 3)  # z = 0 lies 1 from every one-hot failure: never within delta_z
    assert loss(True, outside) == pytest.approx(loss(False, outside))
    spread = torch.eye(3)[[0, 1, 2, 0]].expand(32, 4, 3)  # each failure set holds 1/4 to 3/4 of them
    assert loss(True, spread) != pytest.approx(loss(False, spread))
    with pytest.raises(ValueError, match="stratum_weights=true reads each row's sibling outcomes"):
        policy.config.stratum_weights = True
        policy.forward(rows)
    policy.config.stratum_weights = False
    policy.config.state_failure_sets = 0.5
    with pytest.raises(ValueError, match="state_failure_sets=0.5 reads each row's sibling outcomes"):
        policy.forward(rows)


def test_state_failure_sets_train_on_failures_drawn_from_each_rows_siblings():
    """With every row's failures drawn from its siblings, siblings that all lie outside every option keep
    every row, and siblings at each row's own outcome keep none."""
    policy = make_policy(**{**SETTINGS, "training_stage": "recovery", "state_failure_sets": 1.0}).train()
    policy.model.outcomes.fill(torch.randn(3, 16 * 2), torch.zeros(3, 2), torch.arange(3))
    rows = {"observation.state": torch.randn(32, 2), "action": torch.randn(32, 16, 2)}
    own = policy.model.feature.from_chunk(rows["action"], policy.model.outcomes)

    def kept(siblings: Tensor) -> float:
        batch = {**rows, SIBLING_FEATURES_KEY: siblings, SIBLING_COUNT_KEY: torch.full((32, 1), 4)}
        return policy.forward(batch)[1]["kept_rows"]

    assert kept(torch.zeros(32, 4, 3)) == 1.0
    assert kept(own[:, None].expand(32, 4, 3)) == 0.0


def count_calls(module: torch.nn.Module) -> list[int]:
    rows = []
    module.register_forward_hook(lambda _m, args, _out: rows.append(args[0].shape[0]))
    return rows


def test_a_plan_after_failures_calls_only_the_set_denoiser_once_per_step():
    """At w_s = w_z = 1, w_h = 0, eq. (4)'s failure-set form is eps_{s,F} alone: rows remembering failures
    cost what DP costs, one call per reverse step (here with 4 failures), while rows without failures keep
    using the base."""
    torch.manual_seed(0)
    policy = make_policy(**SETTINGS, w_z=1.0, failure_guard_steps=0)
    policy.model.recovery_trained.fill_(True)
    base_rows, head_rows = count_calls(policy.model.base), count_calls(policy.model.recovery)
    with torch.inference_mode():
        policy.select_action({"observation.state": torch.zeros(3, 2)})
        for option in (0, 1, 0, 1):
            policy.report_failure(rows=[0, 1], z=torch.eye(3)[[option, option]])
        base_rows.clear()
        policy.predict_action_chunk({"observation.state": torch.zeros(3, 2)})
    steps = policy.config.num_inference_steps
    assert head_rows[-steps:] == [2] * steps  # the two failed rows, four failures, one call per step
    assert base_rows == [1] * steps  # the row without failures: eps_s only


@pytest.mark.parametrize(
    "window, guided",
    [
        ({"w_z_steps": 3}, {0, 1, 2}),
        ({"w_z_steps": 8}, set(range(8))),
        ({"w_z_steps": None}, set(range(10))),
    ],
)
def test_w_z_guides_only_its_window_of_steps_and_the_set_denoiser_alone_serves_the_rest(
    window: dict, guided: set[int]
):
    """w_z = 2 on the noisiest reverse steps of the 10 (the first 3, the first 8, every one): there
    eps_s + 2 (eps_{s,F} - eps_s), a base call for the failed rows; elsewhere eps_{s,F} alone. The plan equals
    the one sampled step by step by hand."""
    policy = make_policy(**SETTINGS, w_z=2.0, failure_guard_steps=0, **window)
    policy.model.recovery_trained.fill_(True)
    model = policy.model
    state, history = torch.zeros(2, 2), torch.zeros(2, 0)
    z, z_mask = torch.eye(3)[torch.tensor([[0], [1]])], torch.ones(2, 1, dtype=torch.bool)
    base_rows = count_calls(model.base)
    start = torch.randn(2, 16, 2)
    torch.manual_seed(1)
    with torch.inference_mode():
        plan = model.denoise(start.clone(), state, history, z, z_mask)
    steps = policy.config.num_inference_steps
    assert base_rows == [2] * len(guided)  # the failed rows' eps_s, at the guided steps only

    torch.manual_seed(1)
    sample, ones, no_history = start.clone(), torch.ones(2, 1), torch.zeros(2, 1)
    with torch.inference_mode():
        for index, t in enumerate(model.noise_scheduler.timesteps[:steps]):
            step = torch.full((2,), int(t))
            eps = model.recovery(sample, step, state, z, z_mask)
            if index in guided:
                eps_s = model.base(sample, step, state, ones, history, no_history)
                eps = eps_s + 2.0 * (eps - eps_s)
            sample = model.noise_scheduler.step(eps, t, sample).prev_sample
    torch.testing.assert_close(plan, sample)


@pytest.mark.parametrize("weight", [1.0, 2.5])
def test_the_guard_guides_only_the_last_steps_by_its_classifier_gradient(weight):
    """`failure_guard_steps` 3 of 10: the guard runs on the failed rows at the last three reverse steps only,
    where eps_{s,F} - weight sqrt(1 - alpha_bar) grad log (1 - P(repeat | a_t)) replaces eps_{s,F}
    (`failure_guard_weight`); the plan equals the one sampled step by step by hand."""
    policy = make_policy(**SETTINGS, w_z=1.0, failure_guard_steps=3, failure_guard_weight=weight)
    model = policy.model
    model.recovery_trained.fill_(True)
    model.recovery.guard_trained.fill_(True)
    state, history = torch.zeros(2, 2), torch.zeros(2, 0)
    z, z_mask = torch.eye(3)[torch.tensor([[0], [1]])], torch.ones(2, 1, dtype=torch.bool)
    guard_rows = count_calls(model.recovery.guard)
    start = torch.randn(2, 16, 2)
    torch.manual_seed(1)
    with torch.inference_mode():
        plan = model.denoise(start.clone(), state, history, z, z_mask)
    assert guard_rows == [2] * 3

    torch.manual_seed(1)
    sample = start.clone()
    for index, t in enumerate(model.noise_scheduler.timesteps[:10]):
        step = torch.full((2,), int(t))
        with torch.no_grad():
            eps = model.recovery(sample, step, state, z, z_mask)
        if index >= 7:
            noisy = sample.clone().requires_grad_(True)
            logit = model.recovery.guard(noisy, step, state, z, z_mask)
            (gradient,) = torch.autograd.grad((1 - torch.sigmoid(logit)).log().sum(), noisy)
            eps = eps - weight * (1 - model.noise_scheduler.alphas_cumprod[int(t)]).sqrt() * gradient
        sample = model.noise_scheduler.step(eps, t, sample).prev_sample.detach()
    torch.testing.assert_close(plan, sample)


@pytest.mark.parametrize("guard_steps, reverse_steps", [(4, 2), (11, 10)])
def test_a_guard_longer_than_the_reverse_steps_guards_every_step(guard_steps, reverse_steps):
    """The default guard (4 steps) on a short sampler, or more steps than there are, guards them all, as
    `w_z_steps` does, rather than wrapping around to the last one."""
    policy = make_policy(
        **SETTINGS, failure_guard_steps=guard_steps, num_inference_steps=reverse_steps, w_z_steps=None
    )
    policy.model.recovery_trained.fill_(True)
    policy.model.recovery.guard_trained.fill_(True)
    guard_rows = count_calls(policy.model.recovery.guard)
    z, z_mask = torch.eye(3)[torch.tensor([[0], [1]])], torch.ones(2, 1, dtype=torch.bool)
    with torch.inference_mode():
        policy.model.denoise(torch.randn(2, 16, 2), torch.zeros(2, 2), torch.zeros(2, 0), z, z_mask)
    assert guard_rows == [2] * reverse_steps


def test_a_set_denoiser_saved_before_its_guard_loads_and_refuses_only_the_guard(reaching_root, tmp_path):
    """A trained set-denoiser checkpoint without the guard's weights or fields (saved before the guard
    existed) loads; the guarded steps it now gets by default name the fix, and without them it samples."""
    from lerobot.configs.policies import PreTrainedConfig
    from safetensors.torch import load_file, save_file

    from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

    from fixtures.policy_factory import untrained_checkpoint

    checkpoint = untrained_checkpoint(reaching_root, tmp_path / "head", **{**SETTINGS, "num_primitives": 4})
    weights = load_file(checkpoint / "model.safetensors")
    weights["model.recovery_trained"] = torch.ones((), dtype=torch.bool)
    without_guard = {k: v for k, v in weights.items() if not k.startswith("model.recovery.guard")}
    save_file(without_guard, checkpoint / "model.safetensors")
    saved = json.loads((checkpoint / "config.json").read_text())
    old = {k: v for k, v in saved.items() if not k.startswith("failure_guard_")}
    (checkpoint / "config.json").write_text(json.dumps(old))
    batch = {"observation.state": torch.zeros(1, 2)}
    guarded = CCDPPolicy.from_pretrained(checkpoint)
    assert bool(guarded.model.recovery_trained) and not bool(guarded.model.recovery.guard_trained)
    with torch.inference_mode(), pytest.raises(ValueError, match="--policy.failure_guard_steps=0"):
        guarded.select_action(batch)
        guarded.report_failure(z=torch.eye(4)[[0]])
        guarded.predict_action_chunk(batch)
    config = PreTrainedConfig.from_pretrained(checkpoint, cli_overrides=["--failure_guard_steps=0"])
    policy = CCDPPolicy.from_pretrained(checkpoint, config=config)
    with torch.inference_mode():
        policy.select_action(batch)
        policy.report_failure(z=torch.eye(4)[[0]])
        assert torch.isfinite(policy.predict_action_chunk(batch)).all()


@pytest.mark.parametrize("weight", [1.0, CCDPConfig.failure_guard_weight])
def test_no_guard_at_the_default_or_the_neutral_weight_is_accepted(weight):
    """The guard off at the default weight (a user's --policy.failure_guard_steps=0) or at 1 (a config.json
    saved before the guard was on by default) sets no weight that would do nothing."""
    policy = make_policy(**SETTINGS, failure_guard_steps=0, failure_guard_weight=weight)
    assert (policy.config.failure_guard_steps, policy.config.failure_guard_weight) == (0, weight)


def test_settings_the_set_denoiser_cannot_serve_are_refused_with_the_fix():
    with pytest.raises(ValueError, match="n_obs_steps=1"):
        make_policy(**SETTINGS, n_obs_steps=2, n_action_steps=8)
    with pytest.raises(ValueError, match="--policy.recovery_head=set_denoiser"):
        make_policy(**{**SETTINGS, "recovery_head": "unet"}, w_z_steps=5)
    with pytest.raises(ValueError, match=r"`w_z_steps` must be >= 1"):
        make_policy(**SETTINGS, w_z=2.0, w_z_steps=0)
    with pytest.raises(ValueError, match="--policy.recovery_head=set_denoiser"):
        make_policy(**{**SETTINGS, "recovery_head": "classifier"}, failure_guard_steps=2)
    with pytest.raises(ValueError, match="--policy.failure_guard_steps or remove"):
        make_policy(**SETTINGS, failure_guard_steps=0, failure_guard_weight=2.0)
    with pytest.raises(ValueError, match="`failure_guard_weight` must be >= 0"):
        make_policy(**SETTINGS, failure_guard_steps=2, failure_guard_weight=-1.0)


def test_fourier_octaves_feed_the_set_embedding_z_with_its_sines_and_cosines():
    policy = make_policy(**SETTINGS, z_fourier_octaves=2)
    features = policy.model.recovery.set_embedding[0](torch.tensor([[0.25, -1.0, 0.0]]))
    angles = torch.pi * torch.tensor([0.25, 0.5, -1.0, -2.0, 0.0, 0.0])  # each dim's octaves 0 and 1
    expected = torch.cat([torch.tensor([0.25, -1.0, 0.0]), angles.sin(), angles.cos()])
    torch.testing.assert_close(features, expected[None])


@pytest.mark.parametrize(
    ("z", "given", "octaves"),
    [
        ("final_state", None, 4),
        ("primitive", None, 0),
        ("action", None, 0),
        ("final_state", 0, 0),
        ("primitive", 2, 2),
    ],
)
def test_the_octaves_default_to_what_z_is_and_the_saved_config_holds_the_number(z, given, octaves, tmp_path):
    """A point z (`final_state`) is read in FOURIER_OCTAVES_OF_A_POINT octaves unless set, a label or a chunk
    in none; the policy names the number, so config.json (every later stage's config) holds it."""
    settings = {**SETTINGS, "failure_feature": z, "z_fourier_octaves": given}
    policy = make_policy(**settings, failure_state_dims=[0] if z == "final_state" else [])
    assert policy.config.z_fourier_octaves == octaves
    first = policy.model.recovery.set_embedding[1 if octaves else 0]
    assert first.in_features == policy.config.failure_feature_dim * (1 + 2 * octaves)
    policy.config._save_pretrained(tmp_path)
    assert json.loads((tmp_path / "config.json").read_text())["z_fourier_octaves"] == octaves


def test_a_base_checkpoint_starts_a_recovery_stage_with_fourier_octaves(reaching_root, tmp_path):
    """The octaves are chosen at the recovery stage (`--policy.z_fourier_octaves` beside `--policy.path`): the
    base's untrained set embedding has other keys, so it loads as missing and unexpected keys, not as a size
    mismatch, and the base's weights load unchanged."""
    from lerobot.configs.policies import PreTrainedConfig

    from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

    from fixtures.policy_factory import untrained_checkpoint

    settings = {**SETTINGS, "num_primitives": 4}
    base = untrained_checkpoint(reaching_root, tmp_path / "base", **settings)
    config = PreTrainedConfig.from_pretrained(base)
    config.z_fourier_octaves, config.training_stage = 3, "recovery"
    policy = CCDPPolicy.from_pretrained(base, config=config)
    saved = CCDPPolicy.from_pretrained(base)
    torch.testing.assert_close(policy.model.base.state_dict(), saved.model.base.state_dict())
    assert policy.model.recovery.set_embedding[1].in_features == 4 * (1 + 2 * 3)
    with pytest.raises(ValueError, match="z_fourier_octaves"):
        make_policy(**SETTINGS, z_fourier_octaves=-1)
