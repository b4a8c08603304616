"""Why a recovery method's episodes are lost: each attempt's outcome beside the plans that led to it.

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl python -m lerobot_ccdp.benchmark.trace_failures \
        --checkpoint outputs/benchmark/button_search/recovery/checkpoints/last/pretrained_model \
        --eval-config configs/button_search/eval.json [--seed 1000] [--episodes 100] [--verbose] \
        [--policy.w_z=5 --policy.w_z_steps=3 ...]

Runs lerobot-eval (the method's flags as given, the development seeds, unrendered, on common random
numbers as the pipeline evaluates) with the env and the policy watched: every plan's outcome as the
outcome table looks it up (the z DP* would read), and every attempt's outcome as the env judges it. Prints,
per lost episode, the options tried and the plans' looked-up options, and two counts:
- repeats: how many repeated failures followed a plan that the lookup already placed on a failed option
  (the sampler chose it) rather than on another (the lookup and the env disagree);
- stalls: lost episodes that neither succeeded nor used up their failures, and how many times their last
  attempt's plans switched option (two consecutive plans more than `delta_z` apart).
Under each printed episode (the lost, or with `--verbose` all), where the end effector went (every 10th step)
in every attempt that repeated a failure and, if it stalled, in its last attempt.
With `--probe K`, every attempt's first plan after a failure is also drawn K more times from the same state
and failures, by the method and by the base alone (DP, failures ignored): the shares of those draws that the
lookup places on a failed option, per stage of the task, show where the recovery head leaves the base's
mistake in place. The probe also gives, of the draws off the failed options, the share on the option the
demonstrator prefers there (the env's `preferred_feasible_option`): the base's share is what DP*'s first
accepted candidate keeps, so the method's minus the base's, per state, shows whether composition keeps the
base's proportions (a `final_state` z of observation.state only: a draw's option is the option whose end,
the last target of the env's own plan normalised with the checkpoint's state stats, lies nearest the draw's
z). The extra draws come from torch's global generator: CCDP's and DP*'s own plans (common random numbers,
every DP* candidate from its row's stream) are unchanged.
lerobot-eval's own output goes to a temporary folder.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np
import torch
from lerobot.utils.constants import OBS_STATE
from safetensors.torch import load_file
from torch import Tensor

from lerobot_ccdp.benchmark.pipeline import COMMON_NOISE
from lerobot_ccdp.envs.base import CCDPTaskEnv
from lerobot_ccdp.policy import modeling_ccdp
from lerobot_ccdp.policy.dp_star import nearest_failure_distance
from lerobot_ccdp.policy.failure_features import state_dims
from lerobot_ccdp.policy.samplers import SAMPLERS, PlanRows


@dataclass
class Episode:
    events: list[str] = field(default_factory=list)
    plans: list[tuple[np.ndarray, bool]] = field(default_factory=list)  # (looked-up z, on a failed option)
    attempt_z: np.ndarray | None = None  # the current attempt's latest plan
    repeats: int = 0
    repeats_chosen: int = 0  # repeats whose last plan the lookup placed on a failed option
    repeats_other: int = 0
    switches: int = 0  # in the current attempt
    path: list[np.ndarray] = field(default_factory=list)  # the end effector in the current attempt
    repeat_paths: list[list[np.ndarray]] = field(default_factory=list)  # each repeated failure's attempt
    stage: int = 0  # stages finished so far (the env's)
    done: bool = False
    success: bool = False
    out_of_failures: bool = False


class Tracer:
    """Collects per-row episodes of the batch being evaluated; lerobot-eval's batches follow each other."""

    def __init__(self, delta_z: float):
        self.delta_z = delta_z
        self.rows: dict[int, Episode] = defaultdict(Episode)
        self.env_rows: dict[int, int] = {}
        self.envs: dict[int, CCDPTaskEnv] = {}  # row: its env, for the probe's preferred option
        self.finished: list[Episode] = []
        # stage: (method, DP) shares on a failed option, then (method, DP) preferred shares off them
        self.probes: dict[int, list[tuple[float, float, float, float]]] = defaultdict(list)

    def new_batch(self) -> None:
        self.finished.extend(self.rows[r] for r in sorted(self.rows))
        self.rows.clear()
        self.env_rows.clear()
        self.envs.clear()

    def row_of(self, env: CCDPTaskEnv) -> int:
        return self.env_rows.setdefault(id(env), len(self.env_rows))

    def plan(self, row: int, z: np.ndarray, failed: np.ndarray) -> None:
        episode = self.rows[row]
        if episode.done:
            return
        on_failed = bool(len(failed)) and bool((((failed - z) ** 2).sum(-1) <= self.delta_z).any())
        if episode.attempt_z is not None and ((episode.attempt_z - z) ** 2).sum() > self.delta_z:
            episode.switches += 1
        episode.attempt_z = z
        episode.plans.append((z, on_failed))
        episode.events.append(f"plan {np.round(z, 2).tolist()}{' (a failed option)' if on_failed else ''}")

    def outcome(self, row: int, info: dict, failure: bool, terminated: bool) -> None:
        episode = self.rows[row]
        if episode.done:
            return
        if failure:
            repeat = info["repeated_failures"] > episode.repeats
            if repeat:
                episode.repeats += 1
                chosen = bool(episode.plans) and episode.plans[-1][1]
                episode.repeats_chosen += chosen
                episode.repeats_other += not chosen
                episode.repeat_paths.append(episode.path)
            episode.events.append(f"fail option {info['option']}{' (repeat)' if repeat else ''}")
            episode.attempt_z, episode.switches, episode.path = None, 0, []
        elif info["is_success"]:
            episode.events.append(f"success option {info['option']}")
        episode.success = bool(info["is_success"])
        episode.out_of_failures = terminated and not episode.success
        episode.done = terminated

    def env_reset(self, env: CCDPTaskEnv) -> None:
        """A reset of an env that already stepped in this batch ends its episode (the time limit's)."""
        if id(env) in self.env_rows:
            self.rows[self.env_rows[id(env)]].done = True

    def report(self, verbose: bool) -> None:
        episodes = self.finished
        lost = [e for e in episodes if not e.success]
        stalls = [e for e in lost if not e.out_of_failures]
        chosen = sum(e.repeats_chosen for e in episodes)
        other = sum(e.repeats_other for e in episodes)
        for stage, shares in sorted(self.probes.items()):
            table = np.array(shares)
            method, base = table[:, :2].mean(axis=0)
            high = int((table[:, 0] > 0.5).sum())
            print(
                f"stage {stage}: {len(shares)} first plans after a failure; share of draws on a failed "
                f"option: method {method:.2f}, DP {base:.2f}; states where the method's share > 0.5: {high}"
            )
            both = table[~np.isnan(table[:, 2:]).any(axis=1), 2:]  # states where both drew off the failures
            if len(both):
                gap = both[:, 0] - both[:, 1]
                half = 1.96 * gap.std(ddof=1) / np.sqrt(len(gap)) if len(gap) > 1 else float("nan")
                method, base = both.mean(axis=0)
                print(
                    f"  of the draws off the failed options, the share on the preferred option over "
                    f"{len(both)} states: method {method:.2f}, DP (DP*'s first accepted) {base:.2f}; "
                    f"method - DP {gap.mean():+.3f} [{gap.mean() - half:+.3f}, {gap.mean() + half:+.3f}]"
                )
        for index, episode in enumerate(episodes):
            if not verbose and episode.success:
                continue
            print(f"episode {index}: " + "; ".join(episode.events))
            for path in episode.repeat_paths:
                print(f"  a repeat's attempt, its end effector every 10 steps: {every_tenth(path)}")
            if not episode.success and not episode.out_of_failures:  # stalled
                print(f"  its last attempt's end effector every 10 steps: {every_tenth(episode.path)}")
        print(
            f"\n{len(episodes)} episodes, {len(lost)} lost: {len(lost) - len(stalls)} out of failures, "
            f"{len(stalls)} stalled (their last attempt's plans switched option "
            f"{[e.switches for e in stalls]} times)"
        )
        print(
            f"repeated failures: {chosen + other}; after a plan looked up on a failed option {chosen}, "
            f"on another option {other}"
        )


def every_tenth(path: list[np.ndarray]) -> list[list[float]]:
    return np.round(np.stack(path[::10]), 2).tolist() if path else []


@cache
def state_stats(checkpoint: Path) -> dict[str, Tensor]:
    """The checkpoint preprocessor's normalisation stats (read once per checkpoint)."""
    return load_file(next(checkpoint.glob("policy_preprocessor_step_*_normalizer_processor.safetensors")))


def option_ends(env: CCDPTaskEnv, checkpoint: Path, policy) -> Tensor:
    """Each option's end in z space: the last target of the env's plan for it (the end effector's state,
    laid out as observation.state), normalised as the checkpoint's preprocessor normalises observation.state,
    at the z dims."""
    stats = state_stats(checkpoint)
    key, config = OBS_STATE, policy.config
    raw = torch.tensor([env.plan(option)[-1].target for option in range(env.n_options)], dtype=torch.float32)
    if config.normalization_mapping["STATE"].value == "MIN_MAX":
        low, high = stats[f"{key}.min"], stats[f"{key}.max"]
        normalised = 2 * (raw - low) / (high - low).clamp_min(1e-8) - 1
    else:
        normalised = (raw - stats[f"{key}.mean"]) / stats[f"{key}.std"].clamp_min(1e-8)
    return policy.model.feature.from_frame(normalised)


def probe_shares(
    policy, rows: Tensor, i: int, draws: int, delta_z: float, ends: Tensor | None, preferred: int
) -> tuple[float, float, float, float]:
    """Shares of `draws` plans for the i-th selected row, by the policy's recovery mode and by DP, that the
    lookup places within `delta_z` of one of the row's failures; then, of the draws off the failures, the
    shares whose nearest option end (`ends`) is the `preferred` option (NaN where none is off them, or
    without `ends`)."""
    model, memory = policy.model, policy._rollout.memory
    z, z_mask = policy._rollout.failures.padded(rows)
    state, history = memory.state_condition(rows)[i : i + 1], memory.history_condition(rows)[i : i + 1]
    probe = PlanRows(
        state.repeat_interleave(draws, 0),
        history.repeat_interleave(draws, 0),
        z[i : i + 1].repeat_interleave(draws, 0),
        z_mask[i : i + 1].repeat_interleave(draws, 0),
    )
    failed, kept = [], []
    for mode in (policy.config.recovery_mode, "dp"):
        chunks = SAMPLERS[mode](model, probe)
        z_draws = model.feature.from_chunk(chunks, model.outcomes)
        on_failed = nearest_failure_distance(z_draws[:, None], probe.z, probe.z_mask)[:, 0] <= delta_z
        failed.append(float(on_failed.float().mean()))
        if ends is None or on_failed.all():
            kept.append(float("nan"))
            continue
        option = torch.cdist(z_draws[~on_failed].float(), ends.to(z_draws.device)).argmin(dim=1)
        kept.append(float((option == preferred).float().mean()))
    return failed[0], failed[1], kept[0], kept[1]


@contextmanager
def installed(tracer: Tracer, draws: int, checkpoint: Path) -> Iterator[None]:
    """Wrap the env's step and the policy's reset and sampler while lerobot-eval runs in this process."""
    step, env_reset = CCDPTaskEnv.step, CCDPTaskEnv.reset
    reset, sample = modeling_ccdp.CCDPPolicy.reset, modeling_ccdp.CCDPPolicy._sample

    def traced_step(env, action):
        observation, reward, terminated, truncated, info = step(env, action)
        row, failure = tracer.row_of(env), bool(observation["failure"][0] > 0)  # rows in stepping order
        tracer.envs[row] = env
        episode, stage = tracer.rows[row], env._attempts - env._failures  # stages finished
        if stage > episode.stage and not episode.done and not info["is_success"]:
            episode.events.append(f"stage done with option {info['option']}")
            episode.path = []
        if not episode.done:
            episode.path.append(env.ee_pos.copy())
        episode.stage = stage
        if failure or terminated or truncated:
            tracer.outcome(row, info, failure, terminated or truncated)
        return observation, reward, terminated, truncated, info

    def traced_env_reset(env, *args, **kwargs):
        tracer.env_reset(env)
        return env_reset(env, *args, **kwargs)

    def traced_reset(policy):
        tracer.new_batch()
        reset(policy)

    def traced_sample(policy, rows, noise):
        chunk = sample(policy, rows, noise)
        z = policy.model.feature.from_chunk(chunk, policy.model.outcomes).cpu().numpy()
        failures, mask = policy._rollout.failures.padded(rows)
        for i, row in enumerate(rows.nonzero().flatten().tolist()):
            episode = tracer.rows[row]
            if draws and mask[i].any() and episode.attempt_z is None and not episode.done:
                env = tracer.envs[row]
                config = policy.config  # an option's end is known as the robot's state only
                robot = config.robot_state_feature.shape[0]
                robot_z = config.failure_feature == "final_state" and max(state_dims(config)) < robot
                ends = option_ends(env, checkpoint, policy) if robot_z else None
                preferred = env.preferred_feasible_option()
                shares = probe_shares(policy, rows, i, draws, tracer.delta_z, ends, preferred)
                tracer.probes[episode.stage].append(shares)
                episode.events.append(
                    f"probe: {shares[0]:.2f} on a failed option (DP {shares[1]:.2f}); off them, on the "
                    f"preferred option {preferred} {shares[2]:.2f} (DP {shares[3]:.2f})"
                )
            tracer.plan(row, z[i], failures[i][mask[i]].cpu().numpy())
        return chunk

    CCDPTaskEnv.step, CCDPTaskEnv.reset = traced_step, traced_env_reset
    modeling_ccdp.CCDPPolicy.reset, modeling_ccdp.CCDPPolicy._sample = traced_reset, traced_sample
    try:
        yield
    finally:
        CCDPTaskEnv.step, CCDPTaskEnv.reset = step, env_reset
        modeling_ccdp.CCDPPolicy.reset, modeling_ccdp.CCDPPolicy._sample = reset, sample


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--checkpoint", required=True, help="a recovery checkpoint (pretrained_model folder)")
    parser.add_argument("--eval-config", required=True, help="the task's eval.json")
    parser.add_argument("--seed", type=int, default=1000, help="first seed (default: the development seeds)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--delta-z", type=float, default=0.1, help="the task's delta_z (its recipe's)")
    parser.add_argument("--verbose", action="store_true", help="print every episode, not only the lost")
    parser.add_argument(
        "--probe", type=int, default=0, metavar="K", help="draw each first plan after a failure K more times"
    )
    args, policy_flags = parser.parse_known_args(argv)
    from lerobot.scripts.lerobot_eval import main as lerobot_eval

    tracer = Tracer(args.delta_z)
    argv_before = sys.argv
    with tempfile.TemporaryDirectory() as out, installed(tracer, args.probe, Path(args.checkpoint)):
        sys.argv = [
            "lerobot-eval",
            f"--config_path={args.eval_config}",
            f"--policy.path={args.checkpoint}",
            COMMON_NOISE,
            "--env.render_mode=null",
            f"--eval.n_episodes={args.episodes}",
            f"--seed={args.seed}",
            f"--output_dir={out}/eval",
            *policy_flags,
        ]
        try:
            lerobot_eval()
        finally:
            sys.argv = argv_before
    tracer.new_batch()
    tracer.report(args.verbose)


if __name__ == "__main__":
    main()
