"""How often the failure feature z names the option that actually failed, and what that does to the metrics.

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl .venv/bin/python benchmarks/bench_failure_feature.py \
        --policy-path outputs/benchmark/button_search/recovery/checkpoints/last/pretrained_model \
        --eval-config configs/button_search/eval.json [--modes dp_star ccdp] [--episodes 50]

For a `primitive` policy, runs lerobot-eval (in process, the task's eval settings) once per recovery mode and
per source of the label: `first`, the demonstrated chunk nearest the attempt's first chunk, and `latest`, the
one nearest the chunk executing when the env flagged the failure (the policy's rule). Every recorded z is
matched with the option the env says failed, per vector-env row and in order. Prints one markdown table:
label accuracy, success rate and repeated-failure rate (with 95% intervals).

With `--shares`, it instead samples `--rows` first chunks from one start state of the task (no rollout) and
prints the share of each option (label of the nearest demonstrated chunk) under DP, the recovery head alone
(eq. (4) with w_s = 0, w_z = 1) and CCDP at the checkpoint's weights with either z_reference, after each
option failed once.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import gymnasium as gym
import torch

from lerobot_ccdp.benchmark.comparison import Episodes, MethodMetrics
from lerobot_ccdp.envs import gym_id
from lerobot_ccdp.envs.base import CCDPTaskEnv
from lerobot_ccdp.policy.composition import CompositionWeights
from lerobot_ccdp.policy.failure_features import FailureFeature
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.policy.outcome_index import options_after_failures

SOURCES = ("first", "latest")


@contextmanager
def label_audit(source: str) -> Iterator[collections.Counter]:
    """Counts (true failed option, recorded z label) pairs while lerobot-eval runs in this process.

    Each label is paired with the failure its row flagged last: a failure that ends an episode is never seen
    by the policy, so pairing a row's failures and labels in order would shift every later pair of that
    row."""
    rows: dict[int, int] = {}
    flagged: dict[int, int] = {}
    pairs: collections.Counter = collections.Counter()
    step, record, of_failure = CCDPTaskEnv.step, CCDPPolicy._record_failures, FailureFeature.of_failure

    def audited_step(env, action):
        out = step(env, action)
        row = rows.setdefault(id(env), len(rows))  # SyncVectorEnv steps its envs in row order
        if out[0]["failure"][0] > 0.5:
            flagged[row] = env._last_option
        return out

    def audited_record(policy, failed, z=None):
        record(policy, failed, z)
        buffer = policy._failures
        for r in failed.nonzero().flatten().tolist():
            slot = min(int(buffer.count[r]), buffer.cap) - 1
            if slot >= 0 and r in flagged:
                pairs[(flagged.pop(r), int(buffer.z[r, slot].argmax()))] += 1

    def labelled(feature, frame, attempt_chunk, latest_chunk, outcomes):
        chunk = attempt_chunk if source == "first" else latest_chunk
        return of_failure(feature, frame, attempt_chunk, chunk, outcomes)

    CCDPTaskEnv.step, CCDPPolicy._record_failures, FailureFeature.of_failure = (
        audited_step,
        audited_record,
        labelled,
    )
    try:
        yield pairs
    finally:
        CCDPTaskEnv.step, CCDPPolicy._record_failures, FailureFeature.of_failure = step, record, of_failure


def run_eval(args: argparse.Namespace, mode: str, out: Path) -> MethodMetrics:
    from lerobot.scripts.lerobot_eval import main as lerobot_eval

    argv = sys.argv
    sys.argv = [
        "lerobot-eval",
        f"--config_path={args.eval_config}",
        f"--policy.path={args.policy_path}",
        f"--policy.recovery_mode={mode}",
        f"--eval.n_episodes={args.episodes}",
        f"--output_dir={out}",
    ]
    try:
        lerobot_eval()
    finally:
        sys.argv = argv
    return MethodMetrics.of(Episodes.from_eval_info(out / "eval_info.json"))


def option_shares(args: argparse.Namespace) -> str:
    """Markdown table: option shares of freshly sampled chunks, before and after each option failed."""
    from lerobot.policies.factory import make_pre_post_processors

    policy = CCDPPolicy.from_pretrained(args.policy_path).eval()
    preprocessor, _ = make_pre_post_processors(policy.config, pretrained_path=args.policy_path)
    env_settings = json.loads(Path(args.eval_config).read_text())["env"]
    obs, _ = gym.make(gym_id(env_settings["task"])).reset(seed=args.seed)
    raw = {"observation.state": obs["agent_pos"], "observation.environment_state": obs["environment_state"]}
    batch = preprocessor({k: torch.as_tensor(v)[None].repeat(args.rows, 1) for k, v in raw.items()})
    batch = {k: v for k, v in batch.items() if k.startswith("observation.")}
    k = policy.config.num_primitives
    ccdp = policy.model.weights

    def shares(weights: CompositionWeights, failed: int | None) -> str:
        policy.model.weights = weights
        _, options = options_after_failures(policy, batch, [] if failed is None else [failed])
        return " / ".join(
            f"{v:.2f}" for v in (torch.bincount(options, minlength=k).float() / args.rows).tolist()
        )

    rows = [
        "| failed option | sampler | option shares |",
        "|---|---|---|",
        f"| none | DP | {shares(CompositionWeights(ccdp.w_s, ccdp.w_h, 0.0), None)} |",
    ]
    for failed in range(k):
        rows.append(
            f"| {failed} | recovery head alone | {shares(CompositionWeights(0.0, 0.0, 1.0), failed)} |"
        )
        for reference in ("eps_a", "eps_z_null"):
            weights = CompositionWeights(ccdp.w_s, ccdp.w_h, ccdp.w_z, reference)
            rows.append(
                f"| {failed} | CCDP (w_z = {ccdp.w_z}, against {reference}) | {shares(weights, failed)} |"
            )
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--policy-path", required=True, help="a trained recovery-stage checkpoint (primitive z)"
    )
    parser.add_argument("--eval-config", required=True, help="the task's configs/<task>/eval.json")
    parser.add_argument("--modes", nargs="+", default=["dp_star", "ccdp"], choices=["dp_star", "ccdp"])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--shares", action="store_true", help="option shares of sampled chunks, no rollouts")
    parser.add_argument("--rows", type=int, default=256, help="chunks sampled per row of --shares")
    parser.add_argument("--seed", type=int, default=3, help="env seed of the start state for --shares")
    args = parser.parse_args()
    if args.shares:
        print(option_shares(args))
        return
    rows = [
        "| mode | z label from | failures matched | label accuracy | success | repeated-failure rate |",
        "|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        for mode in args.modes:
            for source in SOURCES:
                with label_audit(source) as pairs:
                    metrics = run_eval(args, mode, Path(tmp) / f"{mode}_{source}")
                matched = sum(pairs.values())
                right = sum(n for (true, z), n in pairs.items() if true == z)
                rows.append(
                    f"| {mode} | {source} chunk | {matched} | {right / max(matched, 1):.3f} | "
                    f"{metrics.success} | {metrics.repeated_failure_rate} |"
                )
    print("\n".join(rows))


if __name__ == "__main__":
    main()
