"""`lerobot_ccdp.benchmark.trace_failures` sorts a lost episode's causes: a repeat after a plan the lookup
already placed on a failed option (the sampler chose it) or on another (lookup and env disagree), and a stall
(no success, failures left) with the option switches of its last attempt."""

from types import SimpleNamespace

import numpy as np
import torch

from lerobot_ccdp.benchmark import trace_failures as trace
from lerobot_ccdp.envs.base import CCDPTaskEnv
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

A, B, C = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
NONE = np.zeros((0, 3))


def info(option: int, repeated: int = 0, success: bool = False) -> dict:
    return {"option": option, "repeated_failures": repeated, "is_success": success}


def test_repeats_are_told_apart_by_the_last_plan_and_stalls_count_their_switches(capsys):
    tracer = trace.Tracer(delta_z=0.1)
    # Row 0: fails on A, plans A again (a failed option), repeats it: the sampler's choice.
    tracer.plan(0, A, NONE)
    tracer.outcome(0, info(0), failure=True, terminated=False)
    tracer.plan(0, A, A[None])
    tracer.outcome(0, info(0, repeated=1), failure=True, terminated=True)
    # Row 1: fails on A, plans B, the env still reports A: the lookup disagrees with the env.
    tracer.plan(1, A, NONE)
    tracer.outcome(1, info(0), failure=True, terminated=False)
    tracer.plan(1, B, A[None])
    tracer.outcome(1, info(0, repeated=1), failure=True, terminated=False)
    # Row 2: fails on A, then its plans switch B -> C -> B and the time limit ends it (a reset).
    tracer.plan(2, A, NONE)
    tracer.outcome(2, info(0), failure=True, terminated=False)
    for z in (B, C, B):
        tracer.plan(2, z, A[None])
    tracer.rows[2].done = True
    tracer.plan(2, C, A[None])  # after its end: ignored
    # Row 3: succeeds.
    tracer.plan(3, B, NONE)
    tracer.outcome(3, info(1, success=True), failure=False, terminated=True)
    tracer.new_batch()

    episodes = tracer.finished
    assert [e.success for e in episodes] == [False, False, False, True]
    assert (episodes[0].repeats_chosen, episodes[0].repeats_other) == (1, 0)
    assert (episodes[1].repeats_chosen, episodes[1].repeats_other) == (0, 1)
    assert episodes[0].out_of_failures and not episodes[2].out_of_failures
    assert episodes[2].switches == 2 and len(episodes[2].plans) == 4
    tracer.report(verbose=False)
    out = capsys.readouterr().out
    assert "4 episodes, 3 lost: 1 out of failures, 2 stalled" in out
    assert "after a plan looked up on a failed option 1, on another option 1" in out


def test_the_probe_counts_the_draws_a_method_and_dp_place_on_a_failed_option(monkeypatch, capsys):
    """`--probe K`: an attempt's first plan after a failure is drawn K more times by the method and by DP from
    the same state and failures; the shares within `delta_z` of a failure are reported per stage, and of the
    draws off the failures, the shares on the preferred option (DP's is what DP*'s first accepted candidate
    keeps)."""
    failed = torch.tensor(A, dtype=torch.float32)

    def chunks_on(options: list[np.ndarray]):
        return lambda model, plan: torch.tensor(np.stack(options), dtype=torch.float32)[:, None].expand(
            -1, 2, -1
        )

    draws = 4
    monkeypatch.setitem(trace.SAMPLERS, "ccdp", chunks_on([B, C, C, C]))
    monkeypatch.setitem(trace.SAMPLERS, "dp", chunks_on([A, B, A, C]))
    memory = SimpleNamespace(
        state_condition=lambda rows: torch.zeros(int(rows.sum()), 2),
        history_condition=lambda rows: torch.zeros(int(rows.sum()), 0),
    )
    failures = SimpleNamespace(
        padded=lambda rows: (failed.expand(1, 1, 3), torch.ones(1, 1, dtype=torch.bool))
    )
    model = SimpleNamespace(
        feature=SimpleNamespace(from_chunk=lambda chunk, outcomes: chunk[:, 0]), outcomes=None
    )
    policy = SimpleNamespace(
        model=model,
        _rollout=SimpleNamespace(memory=memory, failures=failures),
        config=SimpleNamespace(recovery_mode="ccdp"),
    )
    ends = torch.tensor(np.stack([A, B, C]), dtype=torch.float32)  # options 0, 1, 2 end at A, B, C
    shares = trace.probe_shares(policy, torch.tensor([True]), 0, draws, 0.1, ends, preferred=1)
    assert shares == (0.0, 0.5, 0.25, 0.5)  # off the failure: method B C C C, DP B C
    no_ends = trace.probe_shares(policy, torch.tensor([True]), 0, draws, 0.1, None, preferred=1)
    assert no_ends[:2] == (0.0, 0.5) and np.isnan(no_ends[2:]).all()
    tracer = trace.Tracer(delta_z=0.1)
    tracer.probes[1].extend([shares, (0.0, 0.5, 0.75, 0.5)])
    tracer.report(verbose=False)
    out = capsys.readouterr().out
    assert (
        "stage 1: 2 first plans after a failure; share of draws on a failed option: method 0.00, DP 0.50"
        in out
    )
    assert "over 2 states: method 0.50, DP (DP*'s first accepted) 0.50; method - DP +0.000" in out


def test_an_options_end_is_its_plans_last_target_normalised_as_the_checkpoint_normalises_the_state(tmp_path):
    """The probe reads a draw's option as the option whose end lies nearest its z: the env plan's last target,
    through the checkpoint's own state stats (MIN_MAX to [-1, 1]), at the z dims."""
    from safetensors.torch import save_file

    save_file(
        {
            "observation.state.min": torch.tensor([-1.0, 0.0]),
            "observation.state.max": torch.tensor([1.0, 4.0]),
        },
        tmp_path / "policy_preprocessor_step_3_normalizer_processor.safetensors",
    )
    targets = {0: (0.5, 1.0), 1: (-1.0, 4.0)}
    env = SimpleNamespace(n_options=2, plan=lambda option: [None, SimpleNamespace(target=targets[option])])
    config = SimpleNamespace(normalization_mapping={"STATE": SimpleNamespace(value="MIN_MAX")})
    feature = SimpleNamespace(from_frame=lambda frame: frame[..., [1]])  # z: the state's second dim
    policy = SimpleNamespace(config=config, model=SimpleNamespace(feature=feature))
    ends = trace.option_ends(env, tmp_path, policy)
    assert torch.allclose(ends, torch.tensor([[-0.5], [1.0]]))


def test_a_repeats_attempt_and_a_stalled_last_attempt_show_where_the_end_effector_went(capsys):
    """A failure starts the next attempt's path afresh; a repeat keeps its attempt's path; the report prints
    every 10th position of those and of a stalled episode's last attempt."""
    tracer = trace.Tracer(delta_z=0.1)
    first, second = [np.full(3, 0.5), np.full(3, 0.6)], [np.full(3, float(i)) for i in range(12)]
    tracer.rows[0].path.extend(first)
    tracer.outcome(0, info(0), failure=True, terminated=False)
    assert tracer.rows[0].path == [] and tracer.rows[0].repeat_paths == []
    tracer.rows[0].path.extend(second)
    tracer.outcome(0, info(0, repeated=1), failure=True, terminated=False)
    assert tracer.rows[0].repeat_paths == [second] and tracer.rows[0].path == []
    tracer.rows[0].path.extend(first)  # the last attempt, left unfinished by the time limit
    tracer.rows[0].done = True
    tracer.new_batch()
    tracer.report(verbose=False)
    out = capsys.readouterr().out
    assert "a repeat's attempt, its end effector every 10 steps: [[0.0, 0.0, 0.0], [10.0, 10.0, 10.0]]" in out
    assert "its last attempt's end effector every 10 steps: [[0.5, 0.5, 0.5]]" in out


def test_the_tool_traces_a_real_evaluation_and_leaves_the_policy_and_env_unwrapped(
    door_lite_checkpoint, capsys
):
    """`python -m lerobot_ccdp.benchmark.trace_failures` in-process on a DoorOpening-lite checkpoint: every
    episode is reported with every first plan after a failure probed, and the wrapped env and policy methods
    are restored afterwards (a second run, or any later rollout, sees the originals)."""
    originals = (CCDPTaskEnv.step, CCDPTaskEnv.reset, CCDPPolicy.reset, CCDPPolicy._sample)
    trace.main(
        ["--checkpoint", str(door_lite_checkpoint), "--eval-config", "configs/door_opening_lite/eval.json"]
        + ["--episodes", "2", "--probe", "2", "--verbose", "--eval.batch_size=2"]
        + ["--policy.device=cpu", "--policy.num_inference_steps=2"]
    )
    out = capsys.readouterr().out
    assert "\n2 episodes, " in out and "episode 0: " in out and "episode 1: " in out  # --verbose: both
    assert "probe: " in out and "first plans after a failure; share of draws on a failed option" in out
    assert (CCDPTaskEnv.step, CCDPTaskEnv.reset, CCDPPolicy.reset, CCDPPolicy._sample) == originals
