"""Recovery synthesis and recovery training: throughput, recovery-set size, training time, and the paper's
Fig. 2.

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl python -m lerobot_ccdp.benchmark.synthesis_cost \
        [--tasks reaching2d DoorOpening-v0 ...] [--base-steps 1000] [--recovery-steps 3000] [--w-z 3] \
        [--base TASK=CHECKPOINT ...] [--work outputs/synthesis_cost]

For every task: record the demos (`lerobot-ccdp-record`, or the 2-D recorder), train the base with
`lerobot-train` (or take `--base TASK=<pretrained_model>`), run `lerobot-ccdp-synthesize` with the task's
recipe in datasets_recipes/, and train the recovery stage with `lerobot-train`. Prints one table (synthesis
pairs/s, rows synthesised and drawn from demos, wall times of every stage) and, on the 2-D task, saves
fig2_reaching2d.png: sampled chunks from DP, then CCDP after one and after two failed goals (the paper's
Fig. 2). Everything is kept under --work (ignored by git).
"""

from __future__ import annotations

import argparse
import logging
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import torch
import yaml
from lerobot.utils.utils import init_logging

from lerobot_ccdp.benchmark.pipeline import BIN, TASK_GROUPS, task_slug
from lerobot_ccdp.benchmark.work_folder import add_work_arguments, claim_work
from lerobot_ccdp.envs.tasks import TASKS

logger = logging.getLogger(__name__)
CREATED_BY = "lerobot_ccdp.benchmark.synthesis_cost"
RECIPE_FOLDER = Path("datasets_recipes")  # the repository's, run from its root
# Task -> its recipe's name: the 2-D task, and the five benchmark tasks and their lite versions by slug.
RECIPES = {"reaching2d": "reaching2d", **{task: task_slug(task) for task in TASKS}}
FIG2_ROWS = 96
SHARE_ROWS = 512
# (title, recovery_mode, failed goals) of the three Fig. 2 panels, also the rows of the sampler table.
PANELS = [
    ("DP", "dp", []),
    ("CCDP, goal 0 failed", "ccdp", [0]),
    ("CCDP, goals 0 and 1 failed", "ccdp", [0, 1]),
]


def run(*args: str) -> float:
    """Run a console script of this venv; return its wall time (s)."""
    start = time.perf_counter()
    result = subprocess.run(
        [str(BIN / args[0]), *args[1:]],
        capture_output=True,
        text=True,
        env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )
    if result.returncode:
        sys.exit(f"{' '.join(args)} failed:\n{result.stdout[-2000:]}\n{result.stderr[-4000:]}")
    return time.perf_counter() - start


def train(policy_args: list[str], repo_id: str, root: Path, out: Path, steps: int) -> tuple[Path, float]:
    seconds = run(
        "lerobot-train",
        *policy_args,
        f"--dataset.repo_id={repo_id}",
        f"--dataset.root={root}",
        f"--output_dir={out}",
        f"--steps={steps}",
        "--batch_size=64",
        f"--save_freq={steps}",
        "--policy.push_to_hub=false",
        "--num_workers=0",
        "--wandb.enable=false",
        "--log_freq=100",
        "--seed=0",
    )
    return out / "checkpoints" / "last" / "pretrained_model", seconds


def bench_task(
    task: str, work: Path, base: Path | None, base_steps: int, recovery_steps: int, w_z: float
) -> dict:
    name = RECIPES[task]
    recipe_path = RECIPE_FOLDER / f"{name}.yaml"
    recovery = yaml.safe_load(recipe_path.read_text())["recovery"]
    demos, row = work / name / "demos", {"task": task}
    if not demos.exists():
        if task == "reaching2d":
            row["record_s"] = run("python", "-m", "lerobot_ccdp.benchmark.reaching2d", f"--root={demos}")
        else:
            row["record_s"] = run(
                "lerobot-ccdp-record",
                f"--config_path={recipe_path}",
                f"--dataset.repo_id=local/{name}",
                f"--dataset.root={demos}",
            )
    if base is None:
        flags = [
            f"--policy.{k}={v}" for k, v in recovery.items() if k in ("failure_feature", "num_primitives")
        ]
        # the paper's eps_z heads, whose eq. (5) pairs this times and whose samples Fig. 2 draws
        # (docs/benchmarks.md), not the set denoiser these state inputs default to
        head = "--policy.recovery_head=unet"
        base, row["base_train_s"] = train(
            ["--policy.type=ccdp", head, *flags], f"local/{name}", demos, work / name / "base", base_steps
        )
    data = work / name / "recovery_data"
    row["synthesis_s"] = run(
        "lerobot-ccdp-synthesize",
        f"--config_path={recipe_path}",
        f"--dataset.repo_id=local/{name}",
        f"--dataset.root={demos}",
        f"--policy.path={base}",
        f"--output.repo_id=local/{name}_recovery",
        f"--output.root={data}",
        "--overwrite=true",
    )
    result = yaml.safe_load((data / "meta" / "ccdp_recovery_recipe.yaml").read_text())["result"]
    row.update(result)
    row["chunks_per_s"] = result["pool_synthesised"] / result["sampling_seconds"]
    row["pairs_per_s"] = result["rows"] / result["seconds"]
    checkpoint, row["recovery_train_s"] = train(
        [f"--policy.path={base}", "--policy.training_stage=recovery", f"--policy.w_z={w_z}"],
        f"local/{name}_recovery",
        data,
        work / name / "recovery",
        recovery_steps,
    )
    row["checkpoint"] = str(checkpoint)
    return row


def fig2(checkpoint: Path, out: Path) -> dict[str, list[float]]:
    """Sampled chunks on the 2-D task: DP, CCDP after goal 0 failed, after goals 0 and 1 failed (paper
    Fig. 2)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_ccdp.benchmark.reaching2d import GOALS, chunks_after_failures, shares_per_goal
    from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

    policy = CCDPPolicy.from_pretrained(checkpoint).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.2), sharex=True, sharey=True)
    shares = {}
    for ax, (title, mode, failed) in zip(axes, PANELS, strict=True):
        policy.config.recovery_mode = mode
        path, goals = chunks_after_failures(policy, pre, post, failed, FIG2_ROWS)
        shares[title] = shares_per_goal(goals).tolist()
        for trajectory in path:
            ax.plot(trajectory[:, 0], trajectory[:, 1], color="tab:blue", alpha=0.25, lw=1)
        ax.scatter(path[:, -1, 0], path[:, -1, 1], s=8, color="navy", zorder=3)
        ax.scatter(GOALS[:, 0], GOALS[:, 1], s=120, facecolors="none", edgecolors="lightblue", lw=2)
        for goal in failed:
            ax.scatter(*GOALS[goal], s=160, marker="x", color="red", lw=3, zorder=4)
        ax.scatter([0], [0], s=80, color="gold", edgecolors="k", zorder=4)
        ax.set_title(f"{title}\nshares {', '.join(f'{s:.2f}' for s in shares[title])}", fontsize=10)
        ax.set_aspect("equal")
    fig.suptitle(
        "Sampled chunks from the start state (yellow); red x = failed goal; circles = demonstrated goals"
    )
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return shares


def sampler_shares(checkpoint: Path) -> dict[str, dict[str, list[float]]]:
    """Goal shares (SHARE_ROWS chunks) of DP and of CCDP after one and two failed goals, with the checkpoint
    sampled by DDIM and by DDPM (the training is the same for both; only the reverse step differs)."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_ccdp.benchmark.reaching2d import chunks_after_failures, shares_per_goal
    from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

    table = {}
    for scheduler in ("DDIM", "DDPM"):
        config = PreTrainedConfig.from_pretrained(checkpoint)
        config.noise_scheduler_type = scheduler
        policy = CCDPPolicy.from_pretrained(checkpoint, config=config).eval()
        pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
        for label, mode, failed in PANELS:
            policy.config.recovery_mode = mode
            _, goals = chunks_after_failures(policy, pre, post, failed, SHARE_ROWS)
            table.setdefault(label, {})[scheduler] = shares_per_goal(goals).tolist()
    return table


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--tasks", nargs="+", default=["reaching2d", *TASK_GROUPS["all"]], choices=list(RECIPES)
    )
    parser.add_argument(
        "--base",
        nargs="*",
        default=[],
        metavar="TASK=CHECKPOINT",
        help="use an existing base checkpoint instead of training one",
    )
    parser.add_argument("--base-steps", type=int, default=1000)
    parser.add_argument(
        "--recovery-steps", type=int, default=3000, help="as tests/recovery/test_recovery_claim.py"
    )
    parser.add_argument(
        "--w-z",
        type=float,
        default=3.0,
        help="composition weight of the recovery checkpoint, as the task configs",
    )
    add_work_arguments(parser, "outputs/synthesis_cost", "bench_synthesis.py")
    args = parser.parse_args(argv)
    init_logging()
    bases = dict(item.split("=", 1) for item in args.base)
    claim_work(args, CREATED_BY)
    rows = []
    for task in args.tasks:
        rows.append(
            bench_task(
                task,
                args.work,
                Path(bases[task]) if task in bases else None,
                args.base_steps,
                args.recovery_steps,
                args.w_z,
            )
        )
        logger.info("%s: %s", task, rows[-1])
    print(
        f"\nMachine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}, "
        f"{torch.get_num_threads()} threads; base {args.base_steps} steps, "
        f"recovery {args.recovery_steps} steps\n"
    )
    print(
        "| task | pool: sampled + demo chunks | chunks sampled/s (eq. 7) | recovery rows "
        "| rows/s (whole command) | synthesis (s) | base train (s) | recovery train (s) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['task']} | {r['pool_synthesised']} + {r['pool_demo']} | {r['chunks_per_s']:.0f} | "
            f"{r['rows']} | {r['pairs_per_s']:.0f} | {r['seconds']:.1f} | "
            f"{r.get('base_train_s', float('nan')):.0f} | {r['recovery_train_s']:.0f} |"
        )
    if "reaching2d" in args.tasks:
        shares = fig2(
            Path(rows[args.tasks.index("reaching2d")]["checkpoint"]), args.work / "fig2_reaching2d.png"
        )
        print(
            f"\nFig. 2 saved to {args.work / 'fig2_reaching2d.png'}; "
            "goal shares (demonstrated 0.4/0.3/0.2/0.1):"
        )
        for title, share in shares.items():
            print(f"  {title}: {', '.join(f'{s:.2f}' for s in share)}")
        table = sampler_shares(Path(rows[args.tasks.index("reaching2d")]["checkpoint"]))
        print(
            f"\nGoal shares of {SHARE_ROWS} chunks by reverse sampler "
            "(10 steps; demonstrated 0.4/0.3/0.2/0.1):"
        )
        print("| chunks | DDIM | DDPM |\n|---|---|---|")
        for label, by_scheduler in table.items():
            cells = [" / ".join(f"{s:.2f}" for s in by_scheduler[k]) for k in ("DDIM", "DDPM")]
            print(f"| {label} | {cells[0]} | {cells[1]} |")


if __name__ == "__main__":
    main()
