"""`python -m lerobot_ccdp.benchmark.results`: docs/results.md (and the README's results table) written from
the runs' own per-episode outcomes, so every published figure comes from a command at a named commit.

The pipeline saves each run's episodes as JSON (`save_run`; `--publish` copies it beside the published report,
e.g. `docs/benchmark_report.json`). This command reads those files and writes one table per run: per task,
each method's success rate and repeats per attempt after a failure, and CCDP's paired differences of success
against DP, DP* and DP* at CCDP's cost (`lerobot_ccdp.benchmark.paired`: episode i of both resampled
together), and against the paper's eq. (4) with the eps_z heads where a run evaluated it (`ccdp_eps_z`).
A column carries a method's name only if that method alone produced it: runs published with CCDP's plans
redrawn through DP*'s outcome lookup carry "CCDP + k redraws (DP*'s lookup)", and one table never mixes the
two.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lerobot_ccdp.benchmark.comparison import EPS_Z, METHOD_LABELS, has_preference
from lerobot_ccdp.benchmark.episodes import Episodes, Estimate
from lerobot_ccdp.benchmark.paired import (
    cluster_bootstrap,
    paired_difference,
    preference_difference,
    repeats_per_opportunity,
    success_rate,
)
from lerobot_ccdp.benchmark.published import RESULTS_NOTE, RUN_FORMAT, is_results, refuse_unless_ours
from lerobot_ccdp.benchmark.rounds import EARLY, FAMILY_ROUNDS, NEXT_ROUND, PANDA, ROUNDS, Round, span
from lerobot_ccdp.datasets.ownership import NotOwned

FORMAT = RUN_FORMAT
BASELINES = ("dp", "dp_star", "dp_star_matched")
README_BEGIN = "<!-- results:begin (written by python -m lerobot_ccdp.benchmark.results; do not edit) -->"
README_END = "<!-- results:end -->"


_PUBLISHED = (":(top,exclude)docs", ":(top,exclude)README.md")


def commit() -> str:
    """The checked-out commit, marked when the tree has uncommitted changes ("unknown" outside git). The
    documents runs publish into (docs/, the README) do not count: a run that published before another finished
    changes no code the other ran."""
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no", "--", ":(top)", *_PUBLISHED],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return f"{rev} + uncommitted changes" if dirty else rev


def _to_json(values: np.ndarray) -> list[Any]:
    return [None if isinstance(v, float) and math.isnan(v) else v for v in values.tolist()]


def command_line(program: str, argv: list[str]) -> str:
    """`program` and `argv` as one shell line, each absolute path under the working directory (alone or as a
    `--flag=` value) spelled relative to it: a published command names the repository's files, not the
    checkout path of the machine that ran it."""
    here = Path.cwd().resolve()

    def portable(arg: str) -> str:
        flag, equals, value = arg.partition("=") if arg.startswith("-") else ("", "", arg)
        if not equals and flag:
            return arg
        path = Path(value)
        if not path.is_absolute() or not path.resolve().is_relative_to(here):
            return arg
        return f"{flag}{equals}{os.path.relpath(path.resolve(), here)}"

    return shlex.join([*shlex.split(program), *map(portable, argv)])


def save_run(
    path: Path,
    episodes: dict[str, dict[str, Episodes]],
    labels: dict[str, dict[str, str]],
    command: str,
    first_seed: int,
) -> None:
    """Write a run's per-episode outcomes, the command and commit that made them, and each method's label."""
    run = {
        "format": FORMAT,
        "command": command,
        "commit": commit(),
        "first_seed": first_seed,
        "tasks": {
            task: {
                method: {
                    "label": labels[task][method],
                    "episodes": {k: _to_json(v) for k, v in vars(e).items()},
                }
                for method, e in methods.items()
            }
            for task, methods in episodes.items()
        },
    }
    path.write_text(json.dumps(run, indent=1) + "\n")


@dataclass(frozen=True)
class Origin:
    """Where a run file came from: the file, the command that wrote it, the commit it ran at, its tasks."""

    source: Path
    command: str
    commit: str
    tasks: tuple[str, ...]


@dataclass(frozen=True)
class Run:
    """One saved run: where it came from, per task its first seed, and per task and method its label and
    episodes."""

    origins: tuple[Origin, ...]
    first_seeds: dict[str, int]
    labels: dict[str, dict[str, str]]
    episodes: dict[str, dict[str, Episodes]]

    @classmethod
    def load(cls, *paths: Path) -> Run:
        """A run from its run file, or from files that published each task on its own (the pipeline's
        --publish-each), each naming its tasks once. A task's latest round may start at other seeds than the
        rest (the Bartender's from 6000): each task keeps its first seed, and `seeds` names its range."""
        parts = [cls._load_one(path) for path in paths]
        first_seeds, labels, episodes = {}, {}, {}
        for part in parts:
            repeated = sorted(set(part.episodes) & set(episodes))
            if repeated:
                raise ValueError(f"{part.origins[0].source} repeats {repeated}, already in another run file")
            first_seeds.update(part.first_seeds)
            labels.update(part.labels)
            episodes.update(part.episodes)
        return cls(tuple(o for part in parts for o in part.origins), first_seeds, labels, episodes)

    @classmethod
    def _load_one(cls, path: Path) -> Run:
        data = json.loads(path.read_text())
        if data.get("format") != FORMAT:
            raise ValueError(
                f"{path} is not a run saved by the pipeline ({FORMAT}); rerun the pipeline with --publish "
                "to write one beside its report."
            )
        labels, episodes = {}, {}
        for task, methods in data["tasks"].items():
            labels[task] = {m: v["label"] for m, v in methods.items()}
            episodes[task] = {
                m: Episodes(
                    **{
                        k: np.array([np.nan if x is None else x for x in xs], dtype=_DTYPES[k])
                        for k, xs in v["episodes"].items()
                    }
                )
                for m, v in methods.items()
            }
        origin = Origin(path, data["command"], data["commit"], tuple(data["tasks"]))
        return cls((origin,), dict.fromkeys(data["tasks"], data["first_seed"]), labels, episodes)

    def ccdp_column(self) -> str:
        """The label of the CCDP column, the same on every task (a table never mixes CCDP and a hybrid)."""
        found = {labels["ccdp"] for labels in self.labels.values() if "ccdp" in labels}
        if len(found) > 1:
            raise ValueError(
                f"{', '.join(str(o.source) for o in self.origins)} mix {sorted(found)} in one run: a hybrid "
                "gets its own column, so publish each form as a run of its own."
            )
        return found.pop() if found else METHOD_LABELS["ccdp"]


_DTYPES = {
    "success": bool,
    "attempts": int,
    "repeated_failures": int,
    "preference_matched": bool,
    "attempts_after_failure": float,
    "failures": float,
}


def _cell(e: Episodes) -> str:
    repeats = cluster_bootstrap(e, repeats_per_opportunity).value
    return f"{e.success.mean():.2f} / " + ("n/a" if np.isnan(repeats) else f"{repeats:.2f}")


def table(run: Run) -> str:
    """Per task: each method's success / repeats per attempt after a failure, and CCDP's paired differences
    of success against each baseline it ran with and against eq. (4)'s eps_z heads (EPS_Z) where they ran."""
    name = run.ccdp_column()
    methods = [m for m in (*BASELINES, "ccdp", EPS_Z) if any(m in ms for ms in run.episodes.values())]
    refs = [m for m in (*BASELINES, EPS_Z) if m in methods] if "ccdp" in methods else []
    header = [METHOD_LABELS[m] if m != "ccdp" else name for m in methods]
    header += [f"{name} - {METHOD_LABELS[r]}" for r in refs]
    lines = ["| task | " + " | ".join(header) + " |", "|---|" + "---|" * len(header)]
    for task, ms in run.episodes.items():
        cells = [_cell(ms[m]) if m in ms else "-" for m in methods]
        for r in refs:
            both = "ccdp" in ms and r in ms
            cells.append(str(paired_difference(ms["ccdp"], ms[r], success_rate)) if both else "-")
        lines.append(f"| {task.removesuffix('-v0')} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


NON_INFERIORITY_MARGIN = 0.05  # issue 50: CCDP - DP*'s lower bound >= -0.05
REPEATS_TARGET, REPEATS_CEILING = 0.05, 0.10  # issue 50: repeats after a failure <= 0.05, upper bound <= 0.10


def _judged(met: bool, estimate: Estimate) -> str:
    return f"{'met' if met else 'missed'}, {estimate}"


def claims_table(run: Run) -> str:
    """Per task, CCDP's claims judged as issue 50 words them (`met` or `missed`, with the interval): success
    non-inferior to DP*, few repeats after a failure, success above DP, above DP* at CCDP's cost where full
    DP* beats DP ("-" where it does not, so there is nothing for composition to add), and, on the tasks with
    a demonstrated preference, preference adherence non-inferior to DP*'s on the episodes both solved (as the
    report's targets compare it). Empty when the run lacks CCDP or a baseline."""
    name = run.ccdp_column()
    needed = ("ccdp", *BASELINES)
    if not run.episodes or not all(m in ms for ms in run.episodes.values() for m in needed):
        return ""
    lines = [
        f"| task | {name} - DP* >= -{NON_INFERIORITY_MARGIN:.2f} | repeats after a failure "
        f"<= {REPEATS_TARGET:.2f} (upper bound <= {REPEATS_CEILING:.2f}) | {name} > DP | "
        f"{name} > DP* at CCDP's cost, where DP* > DP | "
        f"preference - DP*'s >= -{NON_INFERIORITY_MARGIN:.2f} |",
        "|---|---|---|---|---|---|",
    ]
    for task, ms in run.episodes.items():
        ccdp = ms["ccdp"]
        to_dp_star = paired_difference(ccdp, ms["dp_star"], success_rate)
        repeats = cluster_bootstrap(ccdp, repeats_per_opportunity)
        to_dp = paired_difference(ccdp, ms["dp"], success_rate)
        cells = [
            _judged(to_dp_star.low >= -NON_INFERIORITY_MARGIN, to_dp_star),
            _judged(repeats.value <= REPEATS_TARGET and repeats.high <= REPEATS_CEILING, repeats),
            _judged(to_dp.low > 0, to_dp),
            "-",
            "-",
        ]
        if paired_difference(ms["dp_star"], ms["dp"], success_rate).low > 0:
            to_matched = paired_difference(ccdp, ms["dp_star_matched"], success_rate)
            cells[3] = _judged(to_matched.low > 0, to_matched)
        if has_preference(task):
            preference = preference_difference(ccdp, ms["dp_star"])
            cells[4] = _judged(preference.low >= -NON_INFERIORITY_MARGIN, preference)
        lines.append(f"| {task.removesuffix('-v0')} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def seeds(run: Run) -> str:
    """The run's seeds: one range, or each task's where its tasks were sized differently or started at other
    seeds (episode i of a task has seed first + i)."""
    ranges = {
        task: f"{run.first_seeds[task]}-{run.first_seeds[task] + max(len(e) for e in ms.values()) - 1}"
        for task, ms in run.episodes.items()
    }
    if not ranges:
        return "none"
    if len(set(ranges.values())) == 1:
        return next(iter(ranges.values()))
    return ", ".join(f"{task.removesuffix('-v0')} {span}" for task, span in ranges.items())


def provenance(run: Run, out: Path) -> str:
    """The command and commit that made each of the run's files, linked from `out`'s folder."""

    def made(origin: Origin) -> str:
        link = os.path.relpath(os.path.abspath(origin.source), os.path.abspath(out.parent))
        return f"at commit `{origin.commit}` by `{origin.command}`; per-episode outcomes: [{link}]({link})"

    if len(run.origins) == 1:
        return f"Made {made(run.origins[0])}."
    return "Made task by task:\n\n" + "\n".join(
        f"- {', '.join(origin.tasks)}: {made(origin)}" for origin in run.origins
    )


def section(title: str, run: Run, out: Path) -> str:
    return "\n\n".join(
        [
            f"## {title}",
            f"Seeds {seeds(run)}, the same for every method. {provenance(run, out)}",
            table(run),
            *(
                [f"Issue 50's claims, each `met` or `missed` as the issue defines it:\n\n{claims}"]
                if (claims := claims_table(run))
                else []
            ),
        ]
    )


def _config_title(config: str) -> str:
    """`object_packing_label_free` as the tables name it: "ObjectPacking, no labels"."""
    task, free, labels = config.removesuffix("_label_free"), config.endswith("_label_free"), "labels"
    name = (
        "".join(word.title() for word in task.split("_"))
        .replace("Lite", "-lite")
        .replace("Pixels", " pixels")
    )
    return f"{'the five Panda tasks' if task == 'panda' else name}, {'no labels' if free else labels}"


def _round_row(round_: Round) -> str:
    claims = (
        ("missed: " + round_.outcome if round_.outcome else "all met") if round_.declared else round_.outcome
    )
    return f"| {_config_title(round_.config)} | {span(round_.seeds)} | `{round_.commit}` | {claims} |"


def rounds_section() -> str:
    """Every test round this project has run (`lerobot_ccdp.benchmark.rounds`), one line each, with the count
    per task and label setting, so a published table is read beside how many rounds led to it."""
    order = sorted(
        ROUNDS, key=lambda r: (PANDA.index(r.config.removesuffix("_label_free")), r.config, r.first)
    )
    counts: dict[str, int] = {}
    for round_ in order:
        counts[_config_title(round_.config)] = counts.get(_config_title(round_.config), 0) + 1
    header = "| task | seeds | commit | issue 50's claims |\n|---|---|---|---|"
    family = "\n".join(
        f"| {span(r.members)} | `{r.commit}` | {r.form} | {r.outcome} |" for r in FAMILY_ROUNDS
    )
    return "\n\n".join(
        [
            "## Every test round",
            "A round evaluates settings frozen beforehand, once, on fresh seeds; a miss led to a change on "
            "the development seeds and a new round, so a task's latest table above follows its earlier "
            "misses. "
            "Rounds per task and label setting: "
            + "; ".join(f"{title} {n}" for title, n in counts.items())
            + f'. The next round starts at seed {NEXT_ROUND} ([evaluation.md](evaluation.md), "Seeds"). '
            "Each setting a round froze, and the figure that chose it: [benchmarks.md](benchmarks.md).",
            header + "\n" + "\n".join(map(_round_row, order)),
            "Before the declared rounds, the test seeds 2000-2099 were looked at after every change (spent, "
            "not counted as rounds):",
            header.replace("issue 50's claims", "what they showed")
            + "\n"
            + "\n".join(map(_round_row, EARLY)),
            "The 2-D preference family's test rounds, on members (failed share / preference error after one "
            "and two failures, the mean over 12 members; targets 0.01 / 0.05):",
            "| members | commit | form | outcome |\n|---|---|---|---|\n" + family,
        ]
    )


def write_results(runs: list[tuple[str, Run]], out: Path, command: str, readme: Path | None = None) -> str:
    """docs/results.md from `runs` (title, run), and, with `readme`, the first run's table between the
    README's results markers."""
    text = "\n\n".join(
        [
            "# Results",
            f"<!-- Written by `{command}` at commit {commit()}; rerun it rather than editing. -->",
            "Each cell: success rate / repeats per attempt after a failure. Differences are paired by seed, "
            "with 95% bootstrap intervals; an interval that spans 0 is a tie. How the figures are computed: "
            "[evaluation.md](evaluation.md); what was tried on the way: [benchmarks.md](benchmarks.md).",
            *(section(title, run, out) for title, run in runs),
            rounds_section(),
        ]
    )
    readme_text = with_block(readme, table(runs[0][1])) if readme is not None and runs else None
    out.write_text(text + "\n")  # only once every table and the README's block are known to be writable
    if readme_text is not None:
        readme.write_text(readme_text)
    return text


def with_block(path: Path, body: str, begin: str = README_BEGIN, end: str = README_END) -> str:
    """`path`'s text with `body` between its `begin` and `end` markers (the results table's by default),
    refusing a file without them."""
    text = path.read_text()
    pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise ValueError(f"{path} has no block for this table: add the lines\n{begin}\n{end}")
    return pattern.sub(lambda _: f"{begin}\n{body}\n{end}", text)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--run",
        nargs="+",
        action="append",
        metavar="TITLE JSON",
        required=True,
        help="a section's title and the run file the pipeline published (e.g. docs/benchmark_report.json), "
        "or one file per task of a round published with --publish-each (docs/benchmark/*.json)",
    )
    parser.add_argument("--out", type=Path, default=Path("docs/results.md"))
    parser.add_argument(
        "--readme", type=Path, default=None, help="also put the first run's table in this file"
    )
    args = parser.parse_args(argv)
    short = [run for run in args.run if len(run) < 2]
    if short:
        parser.error(f"--run {short[0][0]!r} names no run file: pass --run TITLE JSON [JSON ...]")
    missing = [path for _, *paths in args.run for path in paths if not Path(path).is_file()]
    if missing:
        sys.exit(
            f"No run file {missing}: the pipeline writes one beside its report with --publish "
            "(make benchmark)."
        )
    try:
        refuse_unless_ours(args.out, is_results, f"holds no note {RESULTS_NOTE} ...", "--out", str(args.out))
        runs = [(title, Run.load(*map(Path, paths))) for title, *paths in args.run]
        command = command_line(
            "python -m lerobot_ccdp.benchmark.results", argv if argv is not None else sys.argv[1:]
        )
        write_results(runs, args.out, command, args.readme)
    except (OSError, ValueError, NotOwned) as error:
        sys.exit(str(error))
    print(f"Wrote {args.out}" + (f" and the table in {args.readme}" if args.readme else ""))


if __name__ == "__main__":
    main()
