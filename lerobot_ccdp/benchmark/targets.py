"""The benchmark's targets for CCDP, each judged from a paired 95% interval (`lerobot_ccdp.benchmark.paired`).

A target is `met` only when the whole interval satisfies it; a difference whose interval straddles the
threshold is `not distinguishable` at the number of episodes run, and every seed giving the same outcome is a
`tie`. Point estimates are shown, but never decide.
"""

from __future__ import annotations

from lerobot_ccdp.benchmark.comparison import METHOD_LABELS, has_preference
from lerobot_ccdp.benchmark.episodes import Episodes, Estimate
from lerobot_ccdp.benchmark.paired import (
    attempts_ratio,
    cluster_bootstrap,
    paired_difference,
    preference_difference,
    repeats_per_attempt,
    success_rate,
    verdict,
)

REPEAT_TARGET = 0.05
# Success non-inferior to DP*: the paired interval of CCDP - DP* lies above -NON_INFERIORITY (issue 50).
NON_INFERIORITY = 0.05
ATTEMPTS_TOLERANCE = 0.15


def target_checks(episodes: dict[str, dict[str, Episodes]]) -> str:
    """Per task: each target, CCDP's value, the reference, the paired interval and the verdict."""
    rows = ["| task | target | measure [95% interval] | verdict |", "|---|---|---|---|"]

    def row(task: str, target: str, measure: str, estimate: Estimate, judged: str) -> None:
        rows.append(f"| {task} | {target} | {measure} {estimate} | {judged} |")

    for task, methods in episodes.items():
        ccdp = methods.get("ccdp")
        if ccdp is None:
            continue
        rate = cluster_bootstrap(ccdp, repeats_per_attempt)
        row(
            task,
            f"repeated-failure rate <= {REPEAT_TARGET}",
            "CCDP rate",
            rate,
            verdict(rate, high_bound=REPEAT_TARGET),
        )
        for ref, low, strict in (
            ("dp", 0.0, True),
            ("dp_star", -NON_INFERIORITY, False),
            ("dp_star_matched", 0.0, True),
        ):
            if ref in methods:
                diff = paired_difference(ccdp, methods[ref], success_rate)
                target = (
                    f"> {METHOD_LABELS[ref]}"
                    if strict
                    else f"non-inferior to {METHOD_LABELS[ref]} (margin {-low:g})"
                )
                row(
                    task,
                    f"success {target}",
                    f"CCDP - {METHOD_LABELS[ref]}",
                    diff,
                    verdict(diff, low_bound=low, strict=strict),
                )
        if has_preference(task) and "dp_star" in methods:
            diff = preference_difference(ccdp, methods["dp_star"])
            row(
                task,
                "preference >= DP* (episodes both solved)",
                "CCDP - DP*",
                diff,
                verdict(diff, low_bound=0.0),
            )
        if "oracle" in methods:
            ratio = attempts_ratio(ccdp, methods["oracle"])
            row(
                task,
                f"attempts within {ATTEMPTS_TOLERANCE:.0%} of oracle (episodes both solved)",
                "CCDP / oracle",
                ratio,
                verdict(ratio, low_bound=1 - ATTEMPTS_TOLERANCE, high_bound=1 + ATTEMPTS_TOLERANCE),
            )
    return "\n".join(rows)
