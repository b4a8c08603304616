"""Choose DP*'s settings on the development seeds, with the care CCDP's settings got.

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl .venv/bin/python benchmarks/tune_dp_star.py --out outputs/benchmark \
        [--candidates 16 32] [--rounds 1 4] [--seed 1000] [--write]

Evaluates DP* (`--policy.recovery_mode=dp_star`) with every pair of `dp_star_candidates` and `dp_star_rounds`
on each task's recovery checkpoint of a `make benchmark` run, through lerobot-eval with the task's eval config
but on the development seeds (`--seed`, default 1000: episode i uses seed + i; the configs' test seeds start at
2000), without rendering. Prints one markdown table (success, repeats per attempt after a failure, attempts of
successful episodes, evaluation time) and picks one setting for all tasks: the highest mean success, then the
fewest repeats, then the cheapest. With `--write` it stores the pick in every task's `configs/<task>/methods.json`,
which `make benchmark` passes to lerobot-eval for DP* (so those evaluations rerun and nothing else).
"""

from __future__ import annotations

import argparse
import itertools
import json
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

from lerobot_ccdp.comparison import MethodMetrics
from lerobot_ccdp.episodes import Episodes
from lerobot_ccdp.pipeline import BIN, CHECKPOINT, TASK_GROUPS, TaskFiles, expand_tasks

REPO = Path(__file__).resolve().parents[1]


def evaluate(files: TaskFiles, candidates: int, rounds: int, seed: int) -> tuple[MethodMetrics, float]:
    """DP* of one setting on one task's recovery checkpoint, evaluated as the benchmark evaluates it but unrendered
    and without `methods.json`: its metrics and the evaluation's wall time."""
    run_dir = files.out / "tune_dp_star" / f"m{candidates}_r{rounds}_seed{seed}"
    shutil.rmtree(run_dir, ignore_errors=True)  # an earlier run's eval_info.json must not be read as this one's
    flags = [f"--policy.dp_star_candidates={candidates}", f"--policy.dp_star_rounds={rounds}",
             "--env.render_mode=null"]
    command = files.eval_command(files.out / "recovery" / CHECKPOINT, "dp_star", seed, run_dir, flags)
    command[0] = str(BIN / command[0])
    start = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{result.stderr[-4000:]}")
    seconds = time.perf_counter() - start
    return MethodMetrics.of(Episodes.from_eval_info(run_dir / "eval_info.json")), seconds


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("outputs/benchmark"), help="a make benchmark run")
    parser.add_argument("--tasks", nargs="+", default=["all"], help=f"task ids, or one of {list(TASK_GROUPS)}")
    parser.add_argument("--candidates", nargs="+", type=int, default=[16, 32])
    parser.add_argument("--rounds", nargs="+", type=int, default=[1, 4])
    parser.add_argument("--seed", type=int, default=1000, help="first development seed")
    parser.add_argument("--write", action="store_true", help="store the pick in configs/<task>/methods.json")
    args = parser.parse_args(argv)
    args.tasks = expand_tasks(args.tasks)
    files = {t: TaskFiles.locate(t, REPO / "configs", REPO / "datasets_recipes", args.out) for t in args.tasks}
    missing = [t for t, f in files.items() if not (f.out / "recovery" / CHECKPOINT).is_dir()]
    if missing:
        raise SystemExit(f"No recovery checkpoint of {missing} under {args.out}; run `make benchmark` first.")
    for task, f in files.items():
        config = f.eval_config()
        test, n = config["seed"], config["eval"]["n_episodes"]
        if args.seed < test + n and test < args.seed + n:
            raise SystemExit(f"--seed {args.seed} overlaps {task}'s test seeds {test}-{test + n - 1}; "
                             "tune on development seeds.")

    settings = list(itertools.product(args.candidates, args.rounds))
    rows, scores = [], {s: [] for s in settings}
    for task, (m, r) in itertools.product(args.tasks, settings):
        metrics, seconds = evaluate(files[task], m, r, args.seed)
        scores[(m, r)].append((metrics.success.value, metrics.repeats_per_opportunity.value))
        rows.append(f"| {task} | {m} | {r} | {metrics.success} | {metrics.repeats_per_opportunity} | "
                    f"{metrics.attempts} | {seconds:.0f} |")
        print(rows[-1], flush=True)
    print("\n| task | candidates | rounds | success | repeats per attempt after a failure | attempts (successes) "
          "| eval s |\n|---|---|---|---|---|---|---|\n" + "\n".join(rows))

    means = {s: np.nanmean(np.array(v, dtype=float), axis=0) for s, v in scores.items()}  # (success, repeats)
    for (m, r), (success, repeats) in means.items():
        print(f"candidates {m}, rounds {r}: mean success {success:.3f}, mean repeats {repeats:.3f}")
    m, r = min(settings, key=lambda s: (-means[s][0], means[s][1], s[0] * s[1]))
    print(f"pick: dp_star_candidates={m}, dp_star_rounds={r} (seeds {args.seed}-{args.seed + 99})")
    if args.write:
        for f in files.values():
            path = f.eval.with_name("methods.json")
            current = json.loads(path.read_text()) if path.is_file() else {}
            current["dp_star"] = {"dp_star_candidates": m, "dp_star_rounds": r}
            path.write_text(json.dumps(current, indent=2) + "\n")
            print(f"wrote {path}")


if __name__ == "__main__":
    main()
