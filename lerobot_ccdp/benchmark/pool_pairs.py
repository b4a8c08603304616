"""Pool paired comparisons over several trainings: is a training change better across training seeds?

    python -m lerobot_ccdp.benchmark.pool_pairs \
        --pair <run>/bartender/tune_ccdp/<A>_seed1000 <run>/bartender/tune_ccdp/<B>_seed1000 \
        --pair <C folder> <D folder> [...]

Each --pair names two evaluations of the same seeds: folders holding lerobot-eval's `eval_info.json`, as
`tune_methods` writes them, or `FILE.json:<task>/tune_<method>/<folder>`, one evaluation of a record that
`tune_methods --publish FILE.json` wrote (e.g. under docs/development/). One is a reference (one training),
the other a variant (the same training changed in one setting, say `--policy.stratum_weights=true`). Prints
each pair's paired difference, variant minus reference, of success and of repeats per attempt after a failure,
then the same over every pair's episodes pooled: a pair stays paired by seed, and the pooled interval
resamples the episodes of all pairs together, as `tune_methods` pools tasks. `--preference` adds the
paired difference of preference adherence on the episodes both evaluations solved (for a task whose
demonstrations prefer one option: ObjectManipulation, ObjectPacking, Bartender). One training decides little
(its seed moves the figures as much as a setting does); pooled pairs of trainings from different seeds say
whether the change holds across them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lerobot_ccdp.benchmark.comparison import paired_cells
from lerobot_ccdp.benchmark.episodes import Episodes
from lerobot_ccdp.benchmark.results import Run


def load(name: Path) -> Episodes:
    """One evaluation: a folder holding its eval_info.json, or `FILE.json:<task>/<key>` of a record."""
    record, sep, key = str(name).partition(".json:")
    if sep:
        task, _, evaluation = key.partition("/")
        try:
            found = Run.load(Path(record + ".json")).episodes
        except (OSError, ValueError) as error:
            raise SystemExit(f"Cannot read the record {record}.json: {error}") from error
        if evaluation not in found.get(task, {}):
            known = [f"{t}/{k}" for t, by in found.items() for k in by]
            raise SystemExit(f"No evaluation {key!r} in {record}.json; it holds {known}.")
        return found[task][evaluation]
    path = name / "eval_info.json"
    if not path.is_file():
        raise SystemExit(f"No eval_info.json in {name}: name a folder an evaluation wrote.")
    return Episodes.from_eval_info(path)


def short(name: Path) -> str:
    """How a pair's row names an evaluation: its folder, after the record's name where it comes from one."""
    record, sep, key = str(name).partition(".json:")
    return f"{Path(record).name}: {Path(key).name}" if sep else name.name


def row(name: str, reference: Episodes, variant: Episodes, preference: bool) -> str:
    return f"| {name} | {len(reference)} | {paired_cells(variant, reference, preference)} |"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--pair",
        nargs=2,
        action="append",
        required=True,
        type=Path,
        metavar=("REFERENCE", "VARIANT"),
        help="two evaluation folders of the same seeds",
    )
    parser.add_argument(
        "--preference",
        action="store_true",
        help="also pair preference adherence (tasks whose demonstrations prefer one option)",
    )
    args = parser.parse_args(argv)
    pairs = [(load(a), load(b)) for a, b in args.pair]
    for (a, b), (ref, var) in zip(args.pair, pairs, strict=True):
        if len(ref) != len(var):
            raise SystemExit(
                f"{a} holds {len(ref)} episodes and {b} {len(var)}: pair evaluations of the same seeds."
            )
    columns = ["success", "repeats"] + ["preference"] * args.preference
    print(
        "| pair | episodes | "
        + " | ".join(f"{c}: variant | reference | variant - reference" for c in columns)
        + " |"
    )
    print("|---|---|" + "---|---|---|" * len(columns))
    for (a, b), (ref, var) in zip(args.pair, pairs, strict=True):
        print(row(f"{short(a)} / {short(b)}", ref, var, args.preference))
    if len(pairs) > 1:
        pooled = [Episodes.concatenate(list(side)) for side in zip(*pairs, strict=True)]
        print(row("pooled", *pooled, args.preference))


if __name__ == "__main__":
    main()
