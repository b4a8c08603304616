"""Files the benchmark writes outside its output folder, into the docs: replaced only where it wrote them.

The pipeline's `--publish` and `--publish-each` write a report (.md), its run file (.json) and its chart
(.png); `python -m lerobot_ccdp.benchmark.results` writes docs/results.md. A file already at such a path is
replaced only when its content says this package wrote it, the rule of the output folders' marker
(`lerobot_ccdp.datasets.ownership`), so a user's file of the same name is never lost:

- a report starts with REPORT_NOTE, and docs/results.md holds RESULTS_NOTE;
- a run file is a JSON object of format RUN_FORMAT (`results.save_run`);
- a chart carries the PNG text CHART_MARK (`comparison.bar_chart`), or, published before that mark, is the
  one a report of ours beside it links.

Every check is made before anything is written, at argument time and again when writing (a run takes hours).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from lerobot_ccdp.datasets.ownership import NotOwned, unmakeable

REPORT_NOTE = "<!-- Written by the command below"
RESULTS_NOTE = "<!-- Written by `python -m lerobot_ccdp.benchmark.results"
RUN_FORMAT = "lerobot_ccdp.results/1"
CHART_MARK = {"Source": "lerobot_ccdp.benchmark.pipeline"}
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _text(path: Path) -> str:
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError):
        return ""


def is_report(path: Path) -> bool:
    return _text(path).startswith(REPORT_NOTE)


def is_results(path: Path) -> bool:
    return RESULTS_NOTE in _text(path)


def is_run_file(path: Path) -> bool:
    try:
        data = json.loads(_text(path))
    except ValueError:
        return False
    return isinstance(data, dict) and data.get("format") == RUN_FORMAT


def png_text(path: Path) -> dict[str, str]:
    """The tEXt chunks of a PNG before its image data (where matplotlib writes its metadata)."""
    try:
        data = path.read_bytes()
    except OSError:
        return {}
    if not data.startswith(PNG_SIGNATURE):
        return {}
    texts, at = {}, len(PNG_SIGNATURE)
    while at + 8 <= len(data):
        length, kind = int.from_bytes(data[at : at + 4], "big"), data[at + 4 : at + 8]
        if kind in (b"IDAT", b"IEND"):
            break
        if kind == b"tEXt":
            key, _, value = data[at + 8 : at + 8 + length].partition(b"\0")
            texts[key.decode("latin-1")] = value.decode("latin-1")
        at += 12 + length
    return texts


def is_chart(path: Path, report: Path) -> bool:
    """Our chart: marked, or (charts published before the mark) linked by our report `report` beside it."""
    marked = CHART_MARK.items() <= png_text(path).items()
    return marked or (is_report(report) and f"]({path.name})" in _text(report))


def refuse_unless_ours(path: Path, ours: Callable[[Path], bool], why: str, flag: str, given: str) -> None:
    """Refuse (NotOwned) writing `path`, named by `flag` `given`, where it holds a file this package did not
    write (`ours` says which, `why` says how it tells) or where it cannot be made; nothing is written."""
    if not (path.exists() or path.is_symlink()):
        problem = unmakeable(path)
        if problem is not None:
            _, folder, reason = problem
            raise NotOwned(
                f"Refusing {flag} {given}: {path} cannot be made: {folder} is {reason}. Nothing was written. "
                f"Choose another {flag}."
            )
        return
    if path.is_file() and ours(path):
        return
    kind = why if path.is_file() else "is not a file"
    raise NotOwned(
        f"Refusing {flag} {given}: {path} {kind}: lerobot_ccdp did not write it. Nothing was written. "
        f"Choose another {flag}, or move or delete {path} yourself if it is yours to lose."
    )


def check_report_targets(report: Path, flag: str, chart: bool = True) -> None:
    """Refuse (NotOwned) publishing a report at `report` (its run file and, with `chart`, its chart beside
    it, named after it) where any of them is a file this package did not write."""
    targets = [
        (report, is_report, f"does not start with the pipeline's note {REPORT_NOTE!r}"),
        (
            report.with_suffix(".json"),
            is_run_file,
            f"is not a run file of the pipeline (format {RUN_FORMAT})",
        ),
    ]
    if chart:
        why = f"is neither a chart the pipeline marked ({CHART_MARK}) nor one its report {report.name} links"
        targets.append((report.with_suffix(".png"), lambda png: is_chart(png, report), why))
    for path, ours, why in targets:
        refuse_unless_ours(path, ours, why, flag, str(report))
