"""CCDP versus LeRobot's stock DiffusionPolicy: planning latency and training speed, side by side.

    HF_HUB_OFFLINE=1 python -m lerobot_ccdp.benchmark.policy_cost [--repeats 50] [--train-steps 30]
        [--cli-steps 60 | --no-cli] [--threads 2] [--recovery-head auto|unet|classifier|set_denoiser]
        [--plan-batch 1] [--horizon 32] [--w-z 5] [--w-z-steps 3] [--guard-steps 4]
        [--out outputs/policy_cost.json]

Both policies get the same UNet and sampling settings (down_dims (32, 64, 128), diffusion_step_embed_dim 32,
kernel 5, 8 groups, n_obs_steps 1, n_action_steps 8, DDIM with 10 inference steps; planning with --horizon,
the Panda tasks' 32, training with 16) and the same inputs: a 2-D robot state plus a small environment state
(stock diffusion needs an image or an env state). CCDP samples with CCDPConfig's defaults unless the flags
say otherwise: the set denoiser (`auto` for these state inputs), `w_z` 5 on the first 3 reverse steps and the
guard on the last 4, the one configuration of docs/benchmarks.md.

(a) Planning latency: one call that samples a chunk for --plan-batch rows (`predict_action_chunk`, no grad;
    lerobot-eval plans for its eval batch, a robot for 1 row), median over --repeats calls after warm-up. The
    failure feature is `primitive` (4 options) with an outcome table of OUTCOME_ROWS demonstrated chunks, so
    DP* (and CCDP with redraws) pay for the outcome lookup as on the Panda tasks. CCDP runs with
    recovery_mode=ccdp, its head marked trained (`recovery_trained.fill_(True)`, so the failure terms are
    really evaluated) and N = 0, 1, 2, 4, 8 failures recorded with `report_failure`; DP* (--dp-star-candidates
    candidates, up to --dp-star-rounds rounds), the compute-matched DP* (--matched-candidates candidates, one
    round) and DP at N = 4 share the same weights. Calls of all configurations are interleaved round-robin so
    background load hits them alike.
(b) Training: forward + backward + grad clipping + Adam step on batches of --batch-size (each policy's own
    batch layout: CCDP's base stage reads history_length extra frames), median over --train-steps interleaved
    steps; then, unless --no-cli, real `lerobot-train` runs of both policy types for --cli-steps steps on a
    reaching2d dataset with an environment state (recorded once under --work), whose steps/s is read from
    lerobot-train's own update/data-loading timers (log intervals after the first).

Prints one table and writes the figures to --out (JSON).
"""

from __future__ import annotations

import argparse
import functools
import json
import logging
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
from lerobot.utils.utils import init_logging

from lerobot_ccdp.benchmark.results import command_line
from lerobot_ccdp.benchmark.work_folder import add_work_arguments, claim_work
from lerobot_ccdp.policy.configuration_ccdp import RECOVERY_HEAD_SETTINGS, CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

logger = logging.getLogger(__name__)
CREATED_BY = "lerobot_ccdp.benchmark.policy_cost"
STATE, ENV, ACTION = "observation.state", "observation.environment_state", "action"
FAILURE_COUNTS = (0, 1, 2, 4, 8)
OUTCOME_ROWS, OPTIONS = 10000, 4
SHARED = {  # the UNet and sampling settings both policies use
    "n_obs_steps": 1,
    "horizon": 16,
    "n_action_steps": 8,
    "down_dims": (32, 64, 128),
    "diffusion_step_embed_dim": 32,
    "kernel_size": 5,
    "n_groups": 8,
    "noise_scheduler_type": "DDIM",
    "num_train_timesteps": 100,
    "num_inference_steps": 10,
}
ENV_REPO_ID = "local/reaching2d_env"
LATENCY_TARGET, TRAIN_TARGET = 1.5, 1.2


def features(env_dim: int) -> tuple[dict, dict]:
    inputs = {STATE: PolicyFeature(FeatureType.STATE, (2,)), ENV: PolicyFeature(FeatureType.ENV, (env_dim,))}
    return inputs, {ACTION: PolicyFeature(FeatureType.ACTION, (2,))}


def make_ccdp(env_dim: int, **overrides) -> CCDPPolicy:
    inputs, outputs = features(env_dim)
    settings = {"failure_feature": "primitive", "num_primitives": OPTIONS, **SHARED, **overrides}
    policy = CCDPPolicy(CCDPConfig(input_features=inputs, output_features=outputs, device="cpu", **settings))
    chunk = policy.config.horizon * policy.config.action_dim
    policy.model.outcomes.fill(
        torch.rand(OUTCOME_ROWS, chunk) * 2 - 1,
        torch.zeros(OUTCOME_ROWS, 2),
        torch.randint(0, OPTIONS, (OUTCOME_ROWS,)),
    )
    return policy


def make_diffusion(env_dim: int, **overrides) -> DiffusionPolicy:
    inputs, outputs = features(env_dim)
    return DiffusionPolicy(
        DiffusionConfig(
            input_features=inputs, output_features=outputs, device="cpu", **{**SHARED, **overrides}
        )
    )


def n_params(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def write_results(results: dict, out: Path) -> dict:
    """Print the table and keep every figure as JSON at `out`."""
    print("\n" + results["table"])
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2))
    logger.info("Wrote %s", out)
    return results


def recorded_once(root: Path, record: Callable[[Path], object]) -> Path:
    """`root`, recorded by `record` unless a complete dataset is there already (reruns reuse their demos)."""
    if not (root / "meta" / "info.json").exists():
        shutil.rmtree(root, ignore_errors=True)
        record(root)
    return root


def interleaved_medians(calls: dict[str, callable], repeats: int, warmup: int) -> dict[str, float]:
    """Median milliseconds per call of each entry, calling the entries round-robin."""
    for _ in range(warmup):
        for fn in calls.values():
            fn()
    times = {name: [] for name in calls}
    for _ in range(repeats):
        for name, fn in calls.items():
            start = time.perf_counter()
            fn()
            times[name].append((time.perf_counter() - start) * 1e3)
    return {name: statistics.median(ts) for name, ts in times.items()}


# ----- (a) planning latency -------------------------------------------------------------------------------


def planning_latency(env_dim: int, repeats: int, warmup: int, args: argparse.Namespace) -> dict:
    torch.manual_seed(0)
    make = functools.partial(
        make_ccdp,
        recovery_head=args.recovery_head,
        horizon=args.horizon,
        w_z=args.w_z,
        w_z_steps=args.w_z_steps,
        failure_guard_steps=args.guard_steps,
    )
    rows = args.plan_batch
    obs = {STATE: torch.randn(rows, 2), ENV: torch.randn(rows, env_dim)}

    diffusion = make_diffusion(env_dim, horizon=args.horizon).eval()
    diffusion.reset()
    diffusion.select_action(dict(obs))  # fills the observation queues predict_action_chunk stacks

    ccdp = make(env_dim).eval()
    state_dict = ccdp.state_dict()
    z_dim = ccdp.config.failure_feature_dim

    def with_failures(policy: CCDPPolicy, n: int) -> CCDPPolicy:
        policy.load_state_dict(state_dict)
        policy.model.recovery_trained.fill_(True)
        if hasattr(policy.model.recovery, "guard_trained"):  # the set denoiser's
            policy.model.recovery.guard_trained.fill_(True)
        policy.eval().reset()
        policy.select_action(dict(obs))
        for _ in range(n):
            policy.report_failure(z=torch.eye(z_dim)[torch.randint(0, z_dim, (rows,))])
        assert int(policy.failure_count()[0]) == n
        return policy

    calls = {"diffusion": lambda: diffusion.predict_action_chunk(dict(obs))}
    ccdp_policies = {n: with_failures(make(env_dim).eval(), n) for n in FAILURE_COUNTS}
    for n, policy in ccdp_policies.items():
        calls[f"ccdp N={n}"] = lambda p=policy: p.predict_action_chunk(dict(obs))
    dp_star = with_failures(
        make(
            env_dim,
            recovery_mode="dp_star",
            dp_star_candidates=args.dp_star_candidates,
            dp_star_rounds=args.dp_star_rounds,
        ),
        4,
    )
    matched = with_failures(
        make(env_dim, recovery_mode="dp_star", dp_star_candidates=args.matched_candidates, dp_star_rounds=1),
        4,
    )
    dp = with_failures(make(env_dim, recovery_mode="dp"), 4)
    calls["dp_star N=4"] = lambda: dp_star.predict_action_chunk(dict(obs))
    calls["dp_star matched N=4"] = lambda: matched.predict_action_chunk(dict(obs))
    calls["dp N=4"] = lambda: dp.predict_action_chunk(dict(obs))

    # Also the full select_action path right after reset (queue/memory set-up included), failure-free.
    def diffusion_select():
        diffusion.reset()
        diffusion.select_action(dict(obs))

    ccdp_plain = with_failures(make(env_dim).eval(), 0)

    def ccdp_select():
        ccdp_plain.reset()
        ccdp_plain.select_action(dict(obs))

    calls["diffusion select_action after reset"] = diffusion_select
    calls["ccdp select_action after reset"] = ccdp_select

    with torch.no_grad():
        medians = interleaved_medians(calls, repeats, warmup)
    base = medians["diffusion"]
    rows = [{"name": name, "median_ms": ms, "ratio_vs_diffusion": ms / base} for name, ms in medians.items()]
    rows[-1]["ratio_vs_diffusion"] = (
        medians["ccdp select_action after reset"] / medians["diffusion select_action after reset"]
    )
    rows[-2]["ratio_vs_diffusion"] = 1.0
    return {
        "rows": rows,
        "params": {
            "diffusion": n_params(diffusion),
            "ccdp_base_unet": n_params(ccdp.model.base),
            "ccdp_recovery_head": n_params(ccdp.model.recovery),
        },
        "ratio_at_n4": medians["ccdp N=4"] / base,
    }


# ----- (b) training step ----------------------------------------------------------------------------------


def ccdp_batch(policy: CCDPPolicy, batch_size: int, env_dim: int) -> dict:
    cfg = policy.config
    frames, steps = cfg.history_length + cfg.n_obs_steps, cfg.history_length + cfg.horizon
    return {
        STATE: torch.rand(batch_size, frames, 2) * 2 - 1,
        ENV: torch.rand(batch_size, frames, env_dim) * 2 - 1,
        ACTION: torch.rand(batch_size, steps, 2) * 2 - 1,
        "action_is_pad": torch.zeros(batch_size, steps, dtype=torch.bool),
    }


def diffusion_batch(policy: DiffusionPolicy, batch_size: int, env_dim: int) -> dict:
    cfg = policy.config
    return {
        STATE: torch.rand(batch_size, cfg.n_obs_steps, 2) * 2 - 1,
        ENV: torch.rand(batch_size, cfg.n_obs_steps, env_dim) * 2 - 1,
        ACTION: torch.rand(batch_size, cfg.horizon, 2) * 2 - 1,
        "action_is_pad": torch.zeros(batch_size, cfg.horizon, dtype=torch.bool),
    }


def training_step_time(env_dim: int, batch_size: int, steps: int, warmup: int) -> dict:
    torch.manual_seed(0)
    ccdp, diffusion = make_ccdp(env_dim).train(), make_diffusion(env_dim).train()
    setups = {
        "diffusion": (diffusion, diffusion_batch(diffusion, batch_size, env_dim)),
        "ccdp": (ccdp, ccdp_batch(ccdp, batch_size, env_dim)),
    }

    def step_fn(policy, batch, optimizer):
        def step():
            optimizer.zero_grad(set_to_none=True)
            loss, _ = policy.forward(batch)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 10.0)
            optimizer.step()

        return step

    calls = {}
    for name, (policy, batch) in setups.items():
        params = policy.get_optim_params()
        params = params if isinstance(params, list) else list(params)
        calls[name] = step_fn(policy, batch, torch.optim.Adam(params, lr=1e-4))
    medians = interleaved_medians(calls, steps, warmup)
    return {
        "median_ms": medians,
        "ratio": medians["ccdp"] / medians["diffusion"],
        "trainable_params": {
            name: sum(p.numel() for p in pol.parameters() if p.requires_grad)
            for name, (pol, _) in setups.items()
        },
    }


# ----- (b') real lerobot-train runs -----------------------------------------------------------------------


def record_env_dataset(root: Path, n_episodes: int) -> None:
    """reaching2d with an environment state (the episode's start position and the four goals' x), so that
    stock diffusion (which needs an image or an env state) trains on it too."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_ccdp.benchmark import reaching2d as r2d

    rng = np.random.default_rng(0)
    counts = np.round(r2d.PREFERENCE * n_episodes).astype(int)
    goals = rng.permutation(np.repeat(np.arange(len(r2d.GOALS)), counts))
    feats = {**r2d.FEATURES, ENV: {"dtype": "float32", "shape": (4,), "names": None}}
    dataset = LeRobotDataset.create(ENV_REPO_ID, fps=r2d.FPS, features=feats, root=root, use_videos=False)
    for goal in goals:
        states, actions = r2d.demo_episode(int(goal), rng)
        env_state = np.concatenate([states[0], [0.0, 1.0]]).astype(np.float32)
        for state, action in zip(states, actions, strict=True):
            dataset.add_frame(
                {
                    STATE: state,
                    ACTION: action,
                    ENV: env_state,
                    "primitive": np.array([goal], dtype=np.int64),
                    "task": "reach a goal",
                }
            )
        dataset.save_episode()
    dataset.finalize()


def cli_args(policy_type: str, root: Path, steps: int, log_freq: int, batch_size: int) -> list[str]:
    common = [
        f"--dataset.repo_id={ENV_REPO_ID}",
        f"--dataset.root={root}",
        f"--steps={steps}",
        f"--batch_size={batch_size}",
        "--policy.push_to_hub=false",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--log_freq={log_freq}",
        f"--save_freq={steps}",
        "--save_checkpoint=false",
        "--seed=0",
        "--policy.device=cpu",
        f"--policy.type={policy_type}",
    ]
    if policy_type == "ccdp":
        return common + ["--policy.failure_feature=primitive", "--policy.num_primitives=4"]
    return common + [
        "--policy.down_dims=[32,64,128]",
        "--policy.diffusion_step_embed_dim=32",
        "--policy.kernel_size=5",
        "--policy.n_groups=8",
        "--policy.n_obs_steps=1",
        "--policy.horizon=16",
        "--policy.n_action_steps=8",
        "--policy.noise_scheduler_type=DDIM",
        "--policy.num_inference_steps=10",
    ]


LOG_LINE = re.compile(r"step:(\S+) .*?updt_s:([\d.]+) data_s:([\d.]+)")


def lerobot_train_speed(name: str, out: Path, train_args: list[str]) -> dict:
    """Steps/s of one real lerobot-train run (`train_args` without --output_dir), from its own timers."""
    shutil.rmtree(out, ignore_errors=True)
    cmd = [str(Path(sys.executable).parent / "lerobot-train"), f"--output_dir={out}", *train_args]
    start = time.perf_counter()
    result = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "HF_HUB_OFFLINE": "1"})
    wall = time.perf_counter() - start
    if result.returncode != 0:
        raise RuntimeError(
            f"lerobot-train ({name}) failed:\n{result.stdout[-2000:]}\n{result.stderr[-4000:]}"
        )
    intervals = [(float(u), float(d)) for _, u, d in LOG_LINE.findall(result.stdout + result.stderr)]
    timed = intervals[1:] or intervals  # the first interval holds the warm-up steps
    if not timed:
        raise RuntimeError(f"no training log lines from lerobot-train ({name}):\n{result.stderr[-3000:]}")
    update_s = statistics.mean(u for u, _ in timed)
    data_s = statistics.mean(d for _, d in timed)
    shutil.rmtree(out, ignore_errors=True)
    return {
        "steps_per_s": 1.0 / (update_s + data_s),
        "update_s": update_s,
        "data_s": data_s,
        "wall_s": wall,
        "intervals": intervals,
        "command": " ".join(cmd),
    }


# ----- report ---------------------------------------------------------------------------------------------


def table(results: dict) -> str:
    lat, train, cli = results["latency"], results["train_step"], results.get("lerobot_train")
    lines = ["| measure | config | value | ratio CCDP / diffusion | target |", "|---|---|---|---|---|"]
    for row in lat["rows"]:
        target = f"<= {LATENCY_TARGET}" if row["name"] == "ccdp N=4" else ""
        lines.append(
            f"| planning latency (ms, median) | {row['name']} | {row['median_ms']:.2f} | "
            f"{row['ratio_vs_diffusion']:.2f}x | {target} |"
        )
    for name in ("diffusion", "ccdp"):
        ratio = f"{train['ratio']:.2f}x" if name == "ccdp" else "1.00x"
        lines.append(
            f"| train step fwd+bwd+Adam (ms, median, batch {results['args']['batch_size']}) | {name} | "
            f"{train['median_ms'][name]:.1f} | {ratio} | {f'<= {TRAIN_TARGET}' if name == 'ccdp' else ''} |"
        )
    if cli:
        for name in ("diffusion", "ccdp"):
            r = cli[name]
            ratio = cli["ratio_step_time"] if name == "ccdp" else 1.0
            lines.append(
                f"| lerobot-train steps/s (update+data, {results['args']['cli_steps']} steps) | {name} | "
                f"{r['steps_per_s']:.2f} (wall {r['wall_s']:.0f} s) | {ratio:.2f}x step time | "
                f"{f'<= {TRAIN_TARGET}' if name == 'ccdp' else ''} |"
            )
    verdict = [
        f"planning N=4: {lat['ratio_at_n4']:.2f}x "
        f"({'OK' if lat['ratio_at_n4'] <= LATENCY_TARGET else 'ABOVE'} target {LATENCY_TARGET}x)",
        f"train step: {train['ratio']:.2f}x "
        f"({'OK' if train['ratio'] <= TRAIN_TARGET else 'ABOVE'} target {TRAIN_TARGET}x)",
    ]
    if cli:
        r = cli["ratio_step_time"]
        verdict.append(
            f"lerobot-train step time: {r:.2f}x "
            f"({'OK' if r <= TRAIN_TARGET else 'ABOVE'} target {TRAIN_TARGET}x)"
        )
    p = lat["params"]
    notes = (
        f"params: diffusion {p['diffusion']:,}; ccdp base UNet {p['ccdp_base_unet']:,} + recovery head "
        f"{p['ccdp_recovery_head']:,}. torch {torch.__version__}, {results['args']['threads']} threads, "
        f"{platform.processor() or platform.machine()}."
    )
    return "\n".join(lines + ["", *verdict, notes])


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50, help="timed planning calls per configuration")
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--train-steps", type=int, default=30, help="timed training steps per policy")
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--env-dim", type=int, default=4, help="size of observation.environment_state")
    parser.add_argument("--dp-star-candidates", type=int, default=32)
    parser.add_argument("--dp-star-rounds", type=int, default=4)
    parser.add_argument(
        "--matched-candidates", type=int, default=2, help="candidates of the compute-matched DP* (one round)"
    )
    parser.add_argument(
        "--plan-batch", type=int, default=1, help="rows planned per call (lerobot-eval: its batch)"
    )
    # The sampling defaults are CCDPConfig's, the one configuration every task is benchmarked with.
    parser.add_argument("--horizon", type=int, default=32, help="planning: chunk length (the Panda tasks')")
    parser.add_argument("--w-z", type=float, default=CCDPConfig.w_z, help="CCDP's failure weight")
    parser.add_argument(
        "--w-z-steps", type=int, default=CCDPConfig.w_z_steps, help="set denoiser: steps that use --w-z"
    )
    parser.add_argument(
        "--guard-steps",
        type=int,
        default=CCDPConfig.failure_guard_steps,
        help="set denoiser: last steps its guard guides (0: none)",
    )
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--recovery-head",
        choices=RECOVERY_HEAD_SETTINGS,
        default=CCDPConfig.recovery_head,
        help="recovery head (auto: the set denoiser for these state inputs)",
    )
    parser.add_argument("--cli-steps", type=int, default=60, help="lerobot-train steps per policy type")
    parser.add_argument("--cli-log-freq", type=int, default=20)
    parser.add_argument("--no-cli", action="store_true", help="skip the lerobot-train runs")
    add_work_arguments(parser, "outputs/policy_cost", "bench_policy.py")
    parser.add_argument("--out", type=Path, default=Path("outputs/policy_cost.json"))
    args = parser.parse_args(argv)
    init_logging()
    claim_work(args, CREATED_BY)

    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    torch.set_num_threads(args.threads)
    results = {"args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}}
    results["args"]["command"] = command_line(
        f"python -m {CREATED_BY}", sys.argv[1:] if argv is None else argv
    )

    logger.info("(a) planning latency ...")
    results["latency"] = planning_latency(args.env_dim, args.repeats, args.warmup, args)
    logger.info("(b) training step ...")
    results["train_step"] = training_step_time(args.env_dim, args.batch_size, args.train_steps, args.warmup)
    if not args.no_cli:
        root = recorded_once(
            args.work / "reaching2d_env", lambda path: record_env_dataset(path, n_episodes=60)
        )
        cli = {}
        for policy_type in ("diffusion", "ccdp"):
            logger.info("(b') lerobot-train --policy.type=%s --steps=%d ...", policy_type, args.cli_steps)
            cli["ccdp" if policy_type == "ccdp" else "diffusion"] = lerobot_train_speed(
                policy_type,
                args.work / f"train_{policy_type}",
                cli_args(policy_type, root, args.cli_steps, args.cli_log_freq, args.batch_size),
            )
        cli["ratio_step_time"] = cli["diffusion"]["steps_per_s"] / cli["ccdp"]["steps_per_s"]
        results["lerobot_train"] = cli

    results["table"] = table(results)
    return write_results(results, args.out)


if __name__ == "__main__":
    main()
