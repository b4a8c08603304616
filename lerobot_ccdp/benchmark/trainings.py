"""`python -m lerobot_ccdp.benchmark.trainings`: a round's table over several trainings of every task.

    python -m lerobot_ccdp.benchmark.trainings --runs outputs/round/seed0 outputs/round/seed1 \
        outputs/round/seed2 [--tasks ...] [--methods ...] [--label-free] [--publish docs/<name>.md]

Each of --runs is one pipeline `--out` (one `--train-seed`), every method evaluated on the same seeds. One
training's figures move with its seed by as much as the margins claims are judged by (issue 114: a second
training of ButtonSearch moved CCDP from 0.98 to 0.90), so per task the table shows each method's success and
repeats per attempt after a failure over all trainings' episodes pooled, beside each training's own figure;
then each CCDP column's pooled paired differences against every other method. A CCDP column is a method
named `ccdp` or `ccdp_*` (a form of it, as the paper's eps_z heads); the methods are the folders the pipeline
writes under `<task>/eval/`, so a new column needs no change here. Intervals (95%) come from a bootstrap that
resamples episodes within each training, paired by seed across methods (`paired`, `strata`): the trainings
are the ones run, and their spread is shown, not drawn again. Evaluations of other seeds, or a task or method
one run lacks, are refused: a paired comparison needs the same seeds everywhere.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numpy as np

from lerobot_ccdp.benchmark.comparison import METHOD_LABELS, has_preference
from lerobot_ccdp.benchmark.episodes import Episodes
from lerobot_ccdp.benchmark.paired import (
    cluster_bootstrap,
    paired_difference,
    preference_difference,
    preference_rate,
    repeats_per_opportunity,
    success_rate,
)
from lerobot_ccdp.benchmark.pipeline import LABEL_FREE, expand_tasks, task_slug
from lerobot_ccdp.benchmark.published import REPORT_NOTE, is_report, refuse_unless_ours
from lerobot_ccdp.benchmark.results import command_line
from lerobot_ccdp.benchmark.rounds import span
from lerobot_ccdp.datasets.ownership import NotOwned
from lerobot_ccdp.envs import TASKS

# eval_info.json does not say which seeds ran; lerobot-eval's log (the pipeline's `logs/eval_<method>.log`)
# does: it logs its configuration as one dict, whose top-level keys stand one space in. Episode i has
# seed + i.
LOGGED_SEED = re.compile(r"^ 'seed': (\d+),?$", re.MULTILINE)
METRICS = {"success": success_rate, "repeats per attempt after a failure": repeats_per_opportunity}
Found = dict[str, list[Episodes]]  # method -> one evaluation per run, in --runs order


def is_ccdp(method: str) -> bool:
    """A CCDP column, compared with every method that is not one."""
    return method == "ccdp" or method.startswith("ccdp_")


def label(method: str) -> str:
    """The name the pipeline's reports give `method`; a column they do not name yet keeps its folder's."""
    return METHOD_LABELS.get(method, method)


def evaluation(run: Path, slug: str, method: str) -> tuple[Episodes, range]:
    """One evaluation as the pipeline wrote it: its episodes (read as `TaskRun.episodes` reads them) and its
    seeds (from lerobot-eval's log beside it)."""
    info = run / slug / "eval" / method / "eval_info.json"
    if not info.is_file():
        raise ValueError(
            f"{run}: {slug} has no evaluation of {method} ({info} is missing): evaluate it in that run "
            f"(the pipeline with --out {run}), or leave it out with --methods."
        )
    episodes = Episodes.from_eval_info(info)
    log = run / slug / "logs" / f"eval_{method}.log"
    found = LOGGED_SEED.findall(log.read_text()) if log.is_file() else []
    if len(found) != 1:
        raise ValueError(
            f"{run}: cannot tell which seeds {slug}'s {method} ran: {log} is not lerobot-eval's log of it "
            "(its configuration names the seed); evaluate it again through the pipeline."
        )
    return episodes, range(int(found[0]), int(found[0]) + len(episodes))


def load_task(runs: list[Path], slug: str, methods: list[str] | None) -> tuple[Found, range]:
    """Every method's evaluation of the task (its folder `slug`) in every run, all of the same seeds; and
    those seeds."""
    held = [{p.name for p in (run / slug / "eval").glob("*") if p.is_dir()} for run in runs]
    for run, names in zip(runs, held, strict=True):
        if not names:
            raise ValueError(
                f"{run} holds no evaluation of {slug} (nothing in {run / slug / 'eval'}): evaluate it there, "
                "or leave the task out with --tasks."
            )
    every = set().union(*held)
    names = methods or [m for m in METHOD_LABELS if m in every] + sorted(every - set(METHOD_LABELS))
    found: Found = {}
    first: tuple[Path, str, range] | None = None
    for method in names:
        found[method] = []
        for run in runs:
            episodes, seeds = evaluation(run, slug, method)
            first = first or (run, method, seeds)
            if seeds != first[2]:
                raise ValueError(
                    f"{run}: {slug}'s {method} ran seeds {span(seeds)} ({len(seeds)} episodes) where "
                    f"{first[0]}'s {first[1]} ran {span(first[2])}: a paired comparison needs the same "
                    f"seeds; evaluate it again (the pipeline's --eval-seed {first[2].start} --eval-episodes "
                    f"{len(first[2])})."
                )
            found[method].append(episodes)
    return found, first[2]


def each(values: list[float]) -> str:
    """Each training's figure, in --runs order."""
    return " / ".join("n/a" if np.isnan(v) else f"{v:.2f}" for v in values)


def preference_within(a: Episodes, b: Episodes, idx: np.ndarray) -> float:
    """Preference adherence of `a` minus `b` on the episodes of `idx` both solved, as
    `preference_difference` computes it over all."""
    both = idx[a.success[idx] & b.success[idx]]
    return preference_rate(a, both) - preference_rate(b, both) if len(both) else float("nan")


def difference_cells(
    a: Episodes, b: Episodes, strata: list[int], trainings: list[np.ndarray], preference: bool
) -> list[str]:
    """`a` - `b` pooled (paired, resampled within trainings) and per training: success, repeats after a
    failure and, with `preference`, preference adherence on the episodes both solved."""
    cells = [
        f"{paired_difference(a, b, stat, strata=strata)} | "
        + each([stat(a, i) - stat(b, i) for i in trainings])
        for stat in METRICS.values()
    ]
    if preference:
        within = each([preference_within(a, b, i) for i in trainings])
        cells.append(f"{preference_difference(a, b, strata)} | {within}")
    return cells


def task_table(task: str, found: Found, seeds: range, runs: list[str]) -> str:
    """Per method the pooled figures and each training's; per CCDP column its pooled paired differences."""
    strata = [len(e) for e in next(iter(found.values()))]
    edges = np.cumsum([0, *strata])
    trainings = [np.arange(lo, hi) for lo, hi in zip(edges[:-1], edges[1:], strict=True)]
    pooled = {m: Episodes.concatenate(parts) for m, parts in found.items()}
    columns = " | ".join(f"{name}: pooled | per training" for name in METRICS)
    lines = [
        f"## {task}",
        "",
        f"Seeds {span(seeds)}, {len(runs)} trainings ({' / '.join(runs)}), {sum(strata)} episodes per "
        "method.",
        "",
        f"| method | {columns} |",
        "|---|" + "---|---|" * len(METRICS),
    ]
    for method, e in pooled.items():
        cells = [
            f"{cluster_bootstrap(e, stat, strata=strata)} | {each([stat(e, idx) for idx in trainings])}"
            for stat in METRICS.values()
        ]
        lines.append(f"| {label(method)} | " + " | ".join(cells) + " |")
    pairs = [(a, b) for a in pooled if is_ccdp(a) for b in pooled if not is_ccdp(b)]
    if not pairs:
        return "\n".join(lines)
    preference = has_preference(task)
    names = [*METRICS, "preference, episodes both solved"] if preference else list(METRICS)
    columns = " | ".join(f"{name}: pooled | per training" for name in names)
    lines += ["", f"| difference | {columns} |", "|---|" + "---|---|" * len(names)]
    for a, b in pairs:
        cells = difference_cells(pooled[a], pooled[b], strata, trainings, preference)
        lines.append(f"| {label(a)} - {label(b)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", nargs="+", type=Path, required=True, help="pipeline --out folders")
    parser.add_argument("--tasks", nargs="+", help="task ids or `all`/`lite`; default: every one held")
    parser.add_argument("--methods", nargs="+", help="method folders; default: every one the runs hold")
    parser.add_argument("--label-free", action="store_true", help="the <task>_label_free evaluations")
    parser.add_argument("--publish", type=Path, help="also write the tables to this markdown file")
    args = parser.parse_args(argv)
    if len({run.resolve() for run in args.runs}) != len(args.runs):
        parser.error("--runs names one folder twice: each training counts once")
    for run in args.runs:
        if not run.is_dir():
            parser.error(f"--runs {run}: no such folder (a pipeline --out)")
    suffix = LABEL_FREE if args.label_free else ""
    held = [t for t in TASKS if any((run / f"{task_slug(t)}{suffix}" / "eval").is_dir() for run in args.runs)]
    tasks = expand_tasks(args.tasks) if args.tasks else held
    if not tasks:
        where = f"<task>{suffix}/eval" if suffix else "<task>/eval (--label-free reads <task>_label_free)"
        parser.error(f"--runs hold no evaluation of any task: no folder {where} in them")
    unknown = [t for t in tasks if t not in TASKS]
    if unknown:
        parser.error(f"--tasks {unknown}: name tasks among {', '.join(TASKS)}")
    names = [run.name for run in args.runs]
    names = names if len(set(names)) == len(names) else [str(run) for run in args.runs]
    command = command_line(
        "python -m lerobot_ccdp.benchmark.trainings", argv if argv is not None else sys.argv[1:]
    )
    try:
        if args.publish:  # before the bootstrap runs, as the pipeline checks its targets before any stage
            why = f"does not start with the note {REPORT_NOTE!r}"
            refuse_unless_ours(args.publish, is_report, why, "--publish", str(args.publish))
        tables = [
            task_table(t, *load_task(args.runs, f"{task_slug(t)}{suffix}", args.methods), names)
            for t in tasks
        ]
    except (ValueError, NotOwned) as error:
        sys.exit(str(error))
    report = "\n\n".join(
        [
            f"# Every method over {len(args.runs)} trainings",
            f"Command: `{command}`",
            "Each cell: the figure over every training's episodes pooled with its 95% interval (a bootstrap "
            "resampling episodes within each training, paired by seed across methods), then each training's.",
            *tables,
        ]
    )
    print(report)
    if args.publish:
        args.publish.parent.mkdir(parents=True, exist_ok=True)
        note = f"{REPORT_NOTE} ({time.strftime('%Y-%m-%d')}); rerun it rather than editing. -->\n"
        args.publish.write_text(note + report + "\n")
        print(f"Published: {args.publish}")


if __name__ == "__main__":
    main()
