"""Choose a recovery method's settings on the development seeds, with the same care for every method.

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl python -m lerobot_ccdp.benchmark.tune_methods --out outputs/benchmark \
        --method dp_star --grid dp_star_candidates=16,32 dp_star_rounds=1,4 [--seed 1000] [--write]
    HF_HUB_OFFLINE=1 MUJOCO_GL=egl python -m lerobot_ccdp.benchmark.tune_methods --out outputs/benchmark \
        --tasks ButtonSearch-v0 --method ccdp --grid w_z=3,5 w_z_steps=3 [--write]
    HF_HUB_OFFLINE=1 MUJOCO_GL=egl python -m lerobot_ccdp.benchmark.tune_methods --out outputs/label_free \
        --label-free --tasks Bartender-v0 --method ccdp --grid w_z=1,2
    HF_HUB_OFFLINE=1 MUJOCO_GL=egl python -m lerobot_ccdp.benchmark.tune_methods --out outputs/label_free \
        --label-free --tasks Bartender-v0 --method dp --checkpoint b7200=<recovery checkpoint>

Evaluates `--method` (lerobot-eval's `--policy.recovery_mode`) with every combination of the `--grid` policy
fields (no `--grid`: the method's `methods.json` settings alone, the only form of DP, which has none) on each
task's recovery checkpoint of a `make benchmark` run (or `python -m
lerobot_ccdp.benchmark.pipeline --train-only`), through lerobot-eval with the task's eval config and the
method's other settings from `methods.json`, but on the development seeds (`--seed`, default 1000, and
`--episodes`, default 100: episode i uses seed + i, whatever size the eval config gives its test round),
without rendering. Prints one markdown table (success, repeats per attempt after a failure, attempts of
successful episodes, why episodes were lost, evaluation time; success and repeats also as paired differences
against the grid's first setting) and picks one setting for the tasks given, their episodes pooled: the grid's
first setting (list the default or the cheapest value first) unless another beats it, paired, with a 95%
interval clear of 0, on success (the highest mean success of those that do) or, where none does, on repeats
without a success interval wholly below 0 (the fewest mean repeats). A tie keeps the first setting. With
`--write` it stores the pick under the method's key of each of those tasks' `configs/<task>/methods.json`,
which `make benchmark` passes to that method's lerobot-eval (so those evaluations rerun and nothing else).
`--report-only` tabulates an earlier run's evaluations.

`--checkpoint NAME=PATH` adds another recovery checkpoint of the same base (a different recovery head, trained
with lerobot-train from `<out>/<task>/base`), evaluated with every grid setting on the same seeds, so the
heads compare paired; `--write` refuses a pick on such a checkpoint, as the head is chosen in the task's
train_base.json. `--heads NAME ...` evaluates only the heads named (`recovery` is the run's own), where
another head's grid needs settings the run's own head has no use for; the differences are then against the
first named head's first setting.

`--method ccdp_eps_z` evaluates the paper's eq. (4) with the eps_z heads, trained from the same base in the
pipeline's stages of that column (`<out>/<task>/recovery_eps_z`: a run with `--methods ... ccdp_eps_z`, or
`--train-only --methods ccdp_eps_z`), with CCDP's sampling and `methods.json`'s `ccdp_eps_z` settings (none of
the set denoiser's, which the eps_z heads refuse); `--write` stores its pick there, and `--against ccdp` pairs
it with the task's own head on the same seeds.

`--against METHOD` also evaluates METHOD at its `methods.json` settings on the same seeds (into
`<task>/tune_<METHOD>/frozen_seed<seed>`) and prints a second table: each row's paired success and repeats
differences against it, and how many test seeds would show success non-inferior to it (interval above
-0.05, issue 50) if the difference and its spread held (`paired.seeds_for_non_inferiority`): the size a test
round needs. On a task whose demonstrations prefer one option it adds the paired difference of preference
adherence on the episodes both solved (issue 50 asks CCDP's to be non-inferior to DP*'s).

`--publish FILE` also writes every evaluation's per-episode outcomes (in `lerobot_ccdp.benchmark.results`'
run format, keyed `<task>` then `tune_<method>/<evaluation folder>`, with the command and commit) to FILE, for
example under docs/development/, so development evidence outlives the machine whose outputs/ made it and
`python -m lerobot_ccdp.benchmark.pool_pairs` can pair evaluations from it
(`FILE:<task>/tune_<method>/<folder>`).

`--baseline-run OTHER` pairs this run with another one (other demos, recipe or training seeds) that was tuned
with the same grid on the same seeds: a third table gives each row's, and `--against`'s method's, paired
success and repeats differences against the same evaluation in OTHER, seed by seed. It only reads OTHER's
evaluations (`--report-only` there first if they are missing; nothing in OTHER is run or replaced).
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from lerobot.utils.utils import init_logging

from lerobot_ccdp.benchmark.comparison import LOST_HEADER, MethodMetrics, has_preference, paired_cells
from lerobot_ccdp.benchmark.episodes import Episodes, LostEpisodes
from lerobot_ccdp.benchmark.paired import (
    paired_difference,
    preference_difference,
    repeats_per_opportunity,
    seeds_for_non_inferiority,
    success_rate,
)
from lerobot_ccdp.benchmark.pipeline import (
    BIN,
    CHECKPOINT,
    CREATED_BY,
    METHODS,
    TASK_GROUPS,
    TaskFiles,
    expand_tasks,
)
from lerobot_ccdp.benchmark.results import command_line, save_run
from lerobot_ccdp.benchmark.targets import NON_INFERIORITY
from lerobot_ccdp.datasets.ownership import MARKER, owner

logger = logging.getLogger(__name__)
CONFIGS, RECIPES = Path("configs"), Path("datasets_recipes")  # the repository's, run from its root
Setting = tuple[tuple[str, Any], ...]  # ((field, value), ...) in the grid's order
Row = tuple[str, Setting]  # (checkpoint name, setting): one row of the table


def parse_grid(items: list[str]) -> list[Setting]:
    """`["dp_star_candidates=16,32", "dp_star_rounds=1,4"]` -> every combination, in the order given."""
    axes = []
    for item in items:
        field, sep, values = item.partition("=")
        if not sep or not field or not values:
            raise SystemExit(f"--grid takes FIELD=V1,V2,... (a policy field and its values), got {item!r}")
        axes.append([(field, value_of(v)) for v in values.split(",")])
    return list(itertools.product(*axes))


def value_of(text: str) -> Any:
    """A grid value as lerobot-eval will parse it: a number or boolean, otherwise the word itself ("each")."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def label(setting: Setting) -> str:
    return ", ".join(f"{field} {value}" for field, value in setting) or "methods.json"


OWN = "recovery"  # the name of the run's own recovery checkpoint, `<out>/<task>/recovery`


def row_label(row: Row) -> str:
    """A table row's name: the setting, after the checkpoint's name where it is not the run's own."""
    name, setting = row
    return label(setting) if name == OWN else f"{name}: {label(setting)}"


def table_rows(grid: list[Setting], checkpoints: dict[str, str], heads: list[str] | None) -> list[Row]:
    """The rows to evaluate: every grid setting on each head of `heads` (default: the run's own, then every
    `--checkpoint`), in that order, so the first row is the reference of every paired difference."""
    known = [OWN, *checkpoints]
    unknown = sorted(set(heads or []) - set(known))
    if unknown:
        raise SystemExit(
            f"--heads names {unknown}, which are not heads of this run: choose from {known} "
            "(add a head with --checkpoint NAME=PATH)."
        )
    # a head named twice runs once
    return [(name, setting) for name in dict.fromkeys(heads or known) for setting in grid]


def run_dir(files: TaskFiles, method: str, checkpoint: str, setting: Setting, seed: int) -> Path:
    name = "_".join(f"{field}{value}" for field, value in setting) or "frozen"  # () is methods.json's
    prefix = "" if checkpoint == OWN else f"{checkpoint}_"
    return files.out / f"tune_{method}" / f"{prefix}{name}_seed{seed}"


def checkpoint_path(files: TaskFiles, checkpoints: dict[str, str], name: str, method: str) -> Path:
    """The recovery checkpoint `name` of one task for `method`: the run's own (the head `method` samples:
    `<task>/recovery_eps_z` for ccdp_eps_z, `<task>/recovery` for the others), or a `--checkpoint` path with
    `{slug}` filled."""
    return (
        files.recovery_out(method) / CHECKPOINT
        if name == OWN
        else Path(checkpoints[name].format(slug=files.out.name))
    )


def evaluate(
    files: TaskFiles, method: str, checkpoint: Path, name: str, setting: Setting, seed: int, episodes: int
) -> float:
    """`method` with `setting` on one task's recovery `checkpoint`, evaluated as the benchmark evaluates it
    but unrendered and on `episodes` episodes, into `run_dir`: the evaluation's wall time."""
    out = run_dir(files, method, name, setting, seed)
    shutil.rmtree(out, ignore_errors=True)  # an earlier run's eval_info.json must not be read as this one's
    flags = files.method_flags(method, dict(setting))
    command = files.eval_command(checkpoint, method, seed, out, flags, episodes=episodes)
    command[0] = str(BIN / command[0])
    start = time.perf_counter()
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{result.stderr[-4000:]}")
    seconds = time.perf_counter() - start
    (out / "seconds.txt").write_text(f"{seconds:.1f}\n")
    return seconds


def pick(rows: list[Row], pooled: dict[Row, Episodes]) -> tuple[Row, str]:
    """The setting to keep and why: the first row unless a paired 95% interval says another is better (success
    first, then repeats per attempt after a failure without a clear loss of success). A tie is not a win."""
    first = rows[0]
    success = {r: paired_difference(pooled[r], pooled[first], success_rate) for r in rows[1:]}
    repeats = {r: paired_difference(pooled[r], pooled[first], repeats_per_opportunity) for r in rows[1:]}
    better = [r for r in rows[1:] if success[r].low > 0]
    if better:
        row = max(better, key=lambda r: (success[r].value, -repeats[r].value))
        return row, f"success {success[row]} over {row_label(first)}"
    fewer = [r for r in rows[1:] if repeats[r].high < 0 and success[r].high >= 0]
    if fewer:
        row = min(fewer, key=lambda r: (repeats[r].value, -success[r].value))
        return row, f"repeats {repeats[row]} against {row_label(first)}, success {success[row]}"
    return first, "the grid's first setting: no other is better by a paired interval clear of 0"


def measured(
    files: TaskFiles, method: str, name: str, setting: Setting, seed: int, episodes: int
) -> tuple[Episodes, float]:
    """The `episodes` episodes of one evaluation already in `run_dir`, and its wall time."""
    out = run_dir(files, method, name, setting, seed)
    if not (out / "eval_info.json").is_file():
        raise SystemExit(
            f"No evaluation of {method} with {label(setting)} under {out}; run this grid on --out "
            f"{files.out.parent} without --report-only."
        )
    found = Episodes.from_eval_info(out / "eval_info.json")
    if len(found) != episodes:
        raise SystemExit(
            f"{out} holds {len(found)} episodes, not --episodes {episodes}; pass --episodes {len(found)} or "
            "run without --report-only to evaluate again."
        )
    seconds = out / "seconds.txt"
    return found, float(seconds.read_text()) if seconds.is_file() else np.nan


def publish(
    path: Path,
    found: dict[str, dict[Path, Episodes]],
    labels: dict[str, dict[Path, str]],
    seed: int,
    argv: list[str],
) -> None:
    """Write every evaluation's episodes to `path` under `<task>` and `tune_<method>/<folder>`: a record that
    does not live in outputs/, with the command and commit that made it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    key = {t: {folder: f"{folder.parent.name}/{folder.name}" for folder in by} for t, by in found.items()}
    save_run(
        path,
        {task: {key[task][folder]: e for folder, e in by.items()} for task, by in found.items()},
        {task: {key[task][folder]: name for folder, name in by.items()} for task, by in labels.items()},
        command_line("python -m lerobot_ccdp.benchmark.tune_methods", argv),
        seed,
    )
    logger.info("Wrote %s", path)


def against(episodes: Episodes, reference: Episodes, preference: bool) -> str:
    """The `--against` table's cells of one row: the reference's success, the paired differences of success
    and repeats, the test seeds that would show non-inferiority, and with `preference` the paired difference
    of preference adherence (else -)."""
    seeds = seeds_for_non_inferiority(episodes, reference, NON_INFERIORITY)
    return (
        f"{MethodMetrics.of(reference).success} | {paired_difference(episodes, reference, success_rate)} | "
        f"{paired_difference(episodes, reference, repeats_per_opportunity)} | {seeds:.0f} | "
        f"{preference_difference(episodes, reference) if preference else '-'}"
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, default=Path("outputs/benchmark"), help="a make benchmark run")
    parser.add_argument(
        "--tasks", nargs="+", default=["all"], help=f"task ids, or one of {list(TASK_GROUPS)}"
    )
    parser.add_argument("--method", choices=list(METHODS), default="dp_star")
    parser.add_argument(
        "--grid",
        nargs="*",
        default=[],
        help="policy fields and the values to try, FIELD=V1,V2,... (none: the methods.json settings)",
    )
    parser.add_argument(
        "--against",
        choices=list(METHODS),
        default=None,
        help="also evaluate this method at its methods.json settings and compare every row with it",
    )
    parser.add_argument(
        "--checkpoint",
        action="append",
        default=[],
        metavar="NAME=PATH",
        help="also evaluate this recovery checkpoint (another head trained from the run's base; "
        "`{slug}` in PATH is the task's folder name), crossed with the grid",
    )
    parser.add_argument(
        "--heads",
        nargs="+",
        default=None,
        metavar="NAME",
        help=f"evaluate only these heads ({OWN!r} is the run's own; default: every head)",
    )
    parser.add_argument(
        "--label-free",
        action="store_true",
        help="the tasks' <task>_label_free settings and folders, of a make benchmark-label-free run",
    )
    parser.add_argument(
        "--baseline-run",
        type=Path,
        default=None,
        help="another make benchmark run tuned with the same grid and seeds: pair each row with it by seed",
    )
    parser.add_argument("--seed", type=int, default=1000, help="first development seed")
    parser.add_argument(
        "--episodes",
        type=int,
        default=100,
        help="episodes per evaluation (seeds seed ... seed + episodes - 1)",
    )
    parser.add_argument("--write", action="store_true", help="store the pick in configs/<task>/methods.json")
    parser.add_argument(
        "--publish",
        type=Path,
        default=None,
        metavar="FILE",
        help="also write every evaluation's per-episode outcomes to FILE (e.g. docs/development/<run>.json)",
    )
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="tabulate the evaluations of an earlier run of this grid under --out, running none",
    )
    args = parser.parse_args(argv)
    init_logging()
    args.tasks = expand_tasks(args.tasks)
    if args.method == "dp" and args.grid:
        raise SystemExit(f"--grid {' '.join(args.grid)}: DP has no settings to tune; give no --grid.")
    if args.write and not args.grid:
        raise SystemExit("--write without --grid: the methods.json settings are already written there.")
    if args.episodes < 1:
        raise SystemExit(f"--episodes {args.episodes}: evaluate at least one episode.")
    if args.publish and args.publish.exists():  # checked before anything runs; a record is never replaced
        raise SystemExit(f"--publish {args.publish} exists; name a new file (a record is never replaced).")
    if owner(args.out.resolve()) != CREATED_BY:  # its evaluations are written, and replaced, inside --out
        raise SystemExit(
            f"--out {args.out} is not an output folder of the pipeline (no {MARKER} of it there). Name a "
            "`make benchmark` folder; one made before ownership markers is marked, with nothing rerun, by "
            "`python -m lerobot_ccdp.benchmark.pipeline --tasks ... --out <it> --train-only --adopt`."
        )
    checkpoints = dict(item.split("=", 1) for item in args.checkpoint if "=" in item)
    if len(checkpoints) != len(args.checkpoint) or OWN in checkpoints:
        raise SystemExit(
            f"--checkpoint takes NAME=PATH with a NAME other than {OWN!r}, got {args.checkpoint}"
        )
    rows_of = table_rows(parse_grid(args.grid), checkpoints, args.heads)
    heads = list(dict.fromkeys(name for name, _ in rows_of))
    files = {
        t: TaskFiles.locate(t, CONFIGS, RECIPES, args.out, label_free=args.label_free) for t in args.tasks
    }
    baselines = {
        t: TaskFiles.locate(t, CONFIGS, RECIPES, args.baseline_run, label_free=args.label_free)
        for t in (args.tasks if args.baseline_run else ())
    }
    paths = {
        t: {name: checkpoint_path(f, checkpoints, name, args.method) for name in heads}
        for t, f in files.items()
    }
    # --against's method on the run's own head it samples
    reference_paths = {
        t: checkpoint_path(f, checkpoints, OWN, args.against) for t, f in files.items() if args.against
    }
    everything = [*(p for by_name in paths.values() for p in by_name.values()), *reference_paths.values()]
    missing = [str(path) for path in everything if not path.is_dir()]
    if missing:
        raise SystemExit(
            f"No recovery checkpoint at {missing}; run `make benchmark` or "
            "`python -m lerobot_ccdp.benchmark.pipeline --train-only` first (with `--methods ccdp_eps_z` for "
            "the eps_z heads of that method), and check the --checkpoint paths."
        )
    for task, f in files.items():
        config = f.eval_config()
        test, n = config["seed"], config["eval"]["n_episodes"]
        last = args.seed + args.episodes - 1
        if args.seed < test + n and test < args.seed + args.episodes:
            raise SystemExit(
                f"--seed {args.seed} overlaps {task}'s test seeds {test}-{test + n - 1}; "
                "tune on development seeds."
            )

    if args.baseline_run and args.baseline_run.resolve() == args.out.resolve():
        raise SystemExit("--baseline-run is --out itself; name another run's folder.")
    # The other run's evaluations, read before any of this run's runs, so that a missing one is named first.
    baseline = {
        (task, row): measured(baselines[task], args.method, *row, args.seed, args.episodes)[0]
        for task in baselines
        for row in rows_of
    }
    if args.against:
        baseline |= {
            (task, None): measured(baselines[task], args.against, OWN, (), args.seed, args.episodes)[0]
            for task in baselines
        }
    if args.against == args.method:
        raise SystemExit(f"--against {args.against} is the method being tuned; name another (e.g. dp_star).")
    rows, scores, by_task = [], {row: [] for row in rows_of}, {row: [] for row in rows_of}
    against_rows, baseline_rows = [], []
    # every evaluation's folder, episodes and row name, for --publish
    found: dict[str, dict[Path, Episodes]] = {t: {} for t in args.tasks}
    names: dict[str, dict[Path, str]] = {t: {} for t in args.tasks}
    for task in args.tasks:
        episodes = {}
        if args.against:
            if not args.report_only:
                evaluate(files[task], args.against, reference_paths[task], OWN, (), args.seed, args.episodes)
            reference, _ = measured(files[task], args.against, OWN, (), args.seed, args.episodes)
            folder = run_dir(files[task], args.against, OWN, (), args.seed)
            found[task][folder], names[task][folder] = reference, f"{args.against} (methods.json)"
        for row in rows_of:
            name, setting = row
            if not args.report_only:
                evaluate(files[task], args.method, paths[task][name], name, setting, args.seed, args.episodes)
            episodes[row], seconds = measured(
                files[task], args.method, name, setting, args.seed, args.episodes
            )
            by_task[row].append(episodes[row])
            folder = run_dir(files[task], args.method, name, setting, args.seed)
            found[task][folder], names[task][folder] = episodes[row], f"{args.method} {row_label(row)}"
            metrics = MethodMetrics.of(episodes[row])
            scores[row].append((metrics.success.value, metrics.repeats_per_opportunity.value))
            first = episodes[rows_of[0]]
            rows.append(
                f"| {task} | {row_label(row)} | {metrics.success} | "
                f"{paired_difference(episodes[row], first, success_rate)} | "
                f"{metrics.repeats_per_opportunity} | "
                f"{paired_difference(episodes[row], first, repeats_per_opportunity)} | "
                f"{metrics.attempts} | {LostEpisodes.of(episodes[row])} | {seconds:.0f} |"
            )
            print(rows[-1], flush=True)
            if args.against:
                cells = against(episodes[row], reference, has_preference(task))
                against_rows.append(f"| {task} | {row_label(row)} | {cells} |")
                print(against_rows[-1], flush=True)
            if args.baseline_run:
                baseline_rows.append(
                    f"| {task} | {args.method} {row_label(row)} | "
                    f"{paired_cells(episodes[row], baseline[task, row])} |"
                )
        if args.baseline_run and args.against:
            baseline_rows.append(
                f"| {task} | {args.against} (methods.json) | "
                f"{paired_cells(reference, baseline[task, None])} |"
            )
    print(
        f"\n{args.method} on seeds {args.seed}-{last}; differences are paired (same seeds) against "
        f"{row_label(rows_of[0])}\n\n"
        "| task | setting | success | difference | repeats per attempt after a failure | difference "
        f"| attempts (successes) | {LOST_HEADER} | eval s |\n|---|---|---|---|---|---|---|---|---|\n"
        + "\n".join(rows)
    )
    if args.against:
        print(
            f"\nAgainst {args.against} at its methods.json settings, same seeds\n\n| task | setting | "
            f"{args.against}'s success | success - {args.against} | repeats - {args.against} | "
            f"test seeds for a lower bound >= -{NON_INFERIORITY} | preference - {args.against} |\n"
            "|---|---|---|---|---|---|---|\n" + "\n".join(against_rows)
        )
    if args.baseline_run:
        print(
            f"\nAgainst the same evaluations of {args.baseline_run}, same seeds\n\n| task | method | "
            "success here | success there | success - there | repeats here | repeats there | "
            "repeats - there |\n|---|---|---|---|---|---|---|---|\n" + "\n".join(baseline_rows)
        )
    if args.publish:
        publish(args.publish, found, names, args.seed, sys.argv[1:] if argv is None else argv)

    means = {r: np.nanmean(np.array(v, dtype=float), axis=0) for r, v in scores.items()}  # (success, repeats)
    for row, (success, repeats) in means.items():
        print(f"{row_label(row)}: mean success {success:.3f}, mean repeats {repeats:.3f}")
    (name, chosen), why = pick(rows_of, {row: Episodes.concatenate(parts) for row, parts in by_task.items()})
    print(f"pick for {args.method}: {row_label((name, chosen))} (seeds {args.seed}-{last}; {why})")
    if args.write and name != OWN:
        raise SystemExit(
            f"Not written: the pick is the checkpoint {name!r}, not the run's own. A recovery head is "
            "part of the task's configs (`recovery_head` in train_base.json), not of methods.json."
        )
    if args.write:
        for f in files.values():
            path = f.eval.with_name("methods.json")
            current = json.loads(path.read_text()) if path.is_file() else {}
            current[args.method] = {**current.get(args.method, {}), **dict(chosen)}
            path.write_text(json.dumps(current, indent=2) + "\n")
            logger.info("Wrote %s", path)


if __name__ == "__main__":
    main()
