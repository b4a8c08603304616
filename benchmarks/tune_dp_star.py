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
from lerobot_ccdp.envs.tasks import TASKS
from lerobot_ccdp.episodes import Episodes
from lerobot_ccdp.pipeline import BIN, CHECKPOINT, task_slug

REPO = Path(__file__).resolve().parents[1]


def evaluate(task: str, out: Path, candidates: int, rounds: int, seed: int) -> tuple[MethodMetrics, float]:
    """DP* of one setting on one task's recovery checkpoint: its metrics and the evaluation's wall time."""
    slug = task_slug(task)
    run_dir = out / slug / "tune_dp_star" / f"m{candidates}_r{rounds}_seed{seed}"
    shutil.rmtree(run_dir, ignore_errors=True)  # an earlier run's eval_info.json must not be read as this one's
    command = [str(BIN / "lerobot-eval"), f"--config_path={REPO / 'configs' / slug / 'eval.json'}",
               f"--policy.path={out / slug / 'recovery' / CHECKPOINT}", "--policy.recovery_mode=dp_star",
               f"--policy.dp_star_candidates={candidates}", f"--policy.dp_star_rounds={rounds}", f"--seed={seed}",
               "--env.render_mode=null", f"--output_dir={run_dir}"]
    start = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{result.stderr[-4000:]}")
    seconds = time.perf_counter() - start
    return MethodMetrics.of(Episodes.from_eval_info(run_dir / "eval_info.json")), seconds


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("outputs/benchmark"), help="a make benchmark run")
    parser.add_argument("--tasks", nargs="+", default=list(TASKS))
    parser.add_argument("--candidates", nargs="+", type=int, default=[16, 32])
    parser.add_argument("--rounds", nargs="+", type=int, default=[1, 4])
    parser.add_argument("--seed", type=int, default=1000, help="first development seed")
    parser.add_argument("--write", action="store_true", help="store the pick in configs/<task>/methods.json")
    args = parser.parse_args(argv)
    missing = [t for t in args.tasks if not (args.out / task_slug(t) / "recovery" / CHECKPOINT).is_dir()]
    if missing:
        raise SystemExit(f"No recovery checkpoint of {missing} under {args.out}; run `make benchmark` first.")
    for task in args.tasks:
        config = json.loads((REPO / "configs" / task_slug(task) / "eval.json").read_text())
        test, n = config["seed"], config["eval"]["n_episodes"]
        if args.seed < test + n and test < args.seed + n:
            raise SystemExit(f"--seed {args.seed} overlaps {task}'s test seeds {test}-{test + n - 1}; "
                             "tune on development seeds.")

    settings = list(itertools.product(args.candidates, args.rounds))
    rows, score = [], {s: [] for s in settings}
    for task, (m, r) in itertools.product(args.tasks, settings):
        metrics, seconds = evaluate(task, args.out, m, r, args.seed)
        score[(m, r)].append((metrics.success.value, metrics.repeats_per_opportunity.value))
        rows.append(f"| {task} | {m} | {r} | {metrics.success} | {metrics.repeats_per_opportunity} | "
                    f"{metrics.attempts} | {seconds:.0f} |")
        print(rows[-1], flush=True)
    print("\n| task | candidates | rounds | success | repeats per attempt after a failure | attempts (successes) "
          "| eval s |\n|---|---|---|---|---|---|---|\n" + "\n".join(rows))

    def rank(setting: tuple[int, int]) -> tuple[float, float, int]:
        success, repeats = np.nanmean(np.array(score[setting], dtype=float), axis=0)
        return (-success, repeats, setting[0] * setting[1])

    for setting in settings:
        success, repeats = np.nanmean(np.array(score[setting], dtype=float), axis=0)
        print(f"candidates {setting[0]}, rounds {setting[1]}: mean success {success:.3f}, mean repeats {repeats:.3f}")
    m, r = min(settings, key=rank)
    print(f"pick: dp_star_candidates={m}, dp_star_rounds={r} (seeds {args.seed}-{args.seed + 99})")
    if args.write:
        for task in args.tasks:
            path = REPO / "configs" / task_slug(task) / "methods.json"
            current = json.loads(path.read_text()) if path.is_file() else {}
            current["dp_star"] = {"dp_star_candidates": m, "dp_star_rounds": r}
            path.write_text(json.dumps(current, indent=2) + "\n")
            print(f"wrote {path}")


if __name__ == "__main__":
    main()
