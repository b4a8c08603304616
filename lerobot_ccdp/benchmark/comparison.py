"""The paper's comparison (its Fig. 5; DESIGN section 8): per task and method, metrics with 95% intervals.

Metrics, from each episode's final env info:
- success rate (Wilson interval over episodes);
- mean attempts of the successful episodes (percentile bootstrap over them); packing and bartender have two
  stages, so their minimum is 2;
- repeated-failure rate per attempt: attempts that repeat an option that already failed in the episode, over
  all attempts (the paper's reading; its denominator includes successful first attempts, which flatters);
- repeated-failure rate per opportunity: the same repeats over the attempts made after at least one failure,
  the only attempts that could repeat one; and the share of episodes with any repeat. Both ratios over
  attempts use an episode-level (cluster) bootstrap, as attempts of one episode are not independent;
- preference adherence: successful episodes whose every choice was the demonstrated preference (Wilson);
- why the other episodes were lost (`LostEpisodes`): a repeated failure, no failed attempt at all, or distinct
  failures only; and how many were solved before any failure, where recovery plays no part
  (`solved_before_any_failure`).

Comparisons between methods are paired by seed: `lerobot_ccdp.benchmark.targets`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_ccdp.benchmark.episodes import Episodes, Estimate, LostEpisodes, solved_before_any_failure
from lerobot_ccdp.benchmark.paired import (
    cluster_bootstrap,
    paired_difference,
    preference_difference,
    repeats_per_attempt,
    repeats_per_opportunity,
    success_rate,
)
from lerobot_ccdp.benchmark.published import CHART_MARK
from lerobot_ccdp.envs.tasks import task_family

# The paper's own form beside CCDP's shipped head: eq. (4) with the eps_z heads (`recovery_head=unet`), one
# sample per plan, a head of its own trained from the same base (`lerobot_ccdp.benchmark.pipeline`).
EPS_Z = "ccdp_eps_z"
METHOD_LABELS = {
    "dp": "DP",
    "dp_star": "DP*",
    "dp_star_matched": "DP* at CCDP's cost",
    "ccdp": "CCDP",
    EPS_Z: "CCDP, eq. (4) eps_z heads",
    "oracle": "no-repeat oracle",
}
METRIC_LABELS = {
    "success": "success rate",
    "attempts": "attempts (successes)",
    "repeated_failure_rate": "repeated-failure rate (per attempt)",
    "repeats_per_opportunity": "repeats per attempt after a failure",
    "episodes_with_repeat": "episodes with a repeat",
    "preference": "preference adherence",
}
CHART_METRICS = ("success", "attempts", "repeats_per_opportunity", "preference")
# Tasks whose demonstrations carry a preference among working options (DESIGN section 7), in both versions.
PREFERENCE_TASKS = ("ObjectManipulation", "ObjectPacking", "Bartender")
Z95 = 1.959963984540054


def has_preference(task: str) -> bool:
    """Whether `task` (e.g. "Bartender-v0" or "Bartender-lite-v0") is one of PREFERENCE_TASKS."""
    return task_family(task) in PREFERENCE_TASKS


def wilson(successes: int, n: int) -> Estimate:
    """Wilson score interval of a proportion: sound at 0 and 1 and for small n, unlike the normal one."""
    if n == 0:
        return Estimate(float("nan"), float("nan"), float("nan"), 0)
    p = successes / n
    denominator = 1 + Z95**2 / n
    centre = (p + Z95**2 / (2 * n)) / denominator
    half = Z95 * np.sqrt(p * (1 - p) / n + Z95**2 / (4 * n**2)) / denominator
    low = 0.0 if successes == 0 else float(centre - half)  # exact at the ends, where round-off would show
    high = 1.0 if successes == n else float(centre + half)
    return Estimate(p, low, high, n)


def bootstrap_mean(values: np.ndarray, n_resamples: int = 2000, seed: int = 0) -> Estimate:
    """Mean with a percentile-bootstrap interval (fixed seed, so reports are reproducible)."""
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return Estimate(float("nan"), float("nan"), float("nan"), 0)
    rng = np.random.default_rng(seed)
    means = rng.choice(values, size=(n_resamples, values.size), replace=True).mean(axis=1)
    low, high = np.percentile(means, [2.5, 97.5])
    return Estimate(float(values.mean()), float(low), float(high), int(values.size))


@dataclass(frozen=True)
class MethodMetrics:
    success: Estimate
    attempts: Estimate
    repeated_failure_rate: Estimate
    repeats_per_opportunity: Estimate
    episodes_with_repeat: Estimate
    preference: Estimate

    @classmethod
    def of(cls, episodes: Episodes) -> MethodMetrics:
        succeeded = episodes.success
        return cls(
            success=wilson(int(succeeded.sum()), len(episodes)),
            attempts=bootstrap_mean(episodes.attempts[succeeded]),
            repeated_failure_rate=cluster_bootstrap(episodes, repeats_per_attempt),
            repeats_per_opportunity=cluster_bootstrap(episodes, repeats_per_opportunity),
            episodes_with_repeat=wilson(int((episodes.repeated_failures > 0).sum()), len(episodes)),
            preference=wilson(int(episodes.preference_matched[succeeded].sum()), int(succeeded.sum())),
        )

    def as_dict(self) -> dict[str, dict[str, float]]:
        return {name: vars(getattr(self, name)) for name in METRIC_LABELS}


def paired_cells(here: Episodes, there: Episodes, preference: bool = False) -> str:
    """Table cells comparing two evaluations of the same seeds: success here and there and its paired
    difference (here minus there), then the same for repeats per attempt after a failure and, with
    `preference` (a task whose demonstrations prefer one option), for preference adherence on the episodes
    both solved (`preference_difference`)."""
    a, b = MethodMetrics.of(here), MethodMetrics.of(there)
    cells = (
        f"{a.success} | {b.success} | {paired_difference(here, there, success_rate)} | "
        f"{a.repeats_per_opportunity} | {b.repeats_per_opportunity} | "
        f"{paired_difference(here, there, repeats_per_opportunity)}"
    )
    if preference:
        cells += f" | {a.preference} | {b.preference} | {preference_difference(here, there)}"
    return cells


Results = dict[str, dict[str, MethodMetrics]]  # task -> method -> metrics
Labels = dict[str, dict[str, str]]  # task -> method -> the name its figures carry, where not METHOD_LABELS'


def label_of(task: str, method: str, labels: Labels | None) -> str:
    """The name `method`'s figures on `task` carry: its own label in `labels` (a hybrid's), else
    METHOD_LABELS."""
    return (labels or {}).get(task, {}).get(method, METHOD_LABELS[method])


def markdown_table(results: Results, labels: Labels | None = None) -> str:
    """One row per task and method, each metric as `value [95% interval]`."""
    lines = [
        "| task | method | episodes | " + " | ".join(METRIC_LABELS.values()) + " |",
        "|---|---|---|" + "---|" * len(METRIC_LABELS),
    ]
    for task, methods in results.items():
        for method, metrics in methods.items():
            cells = " | ".join(str(getattr(metrics, name)) for name in METRIC_LABELS)
            lines.append(f"| {task} | {label_of(task, method, labels)} | {metrics.success.n} | {cells} |")
    return "\n".join(lines)


LOST_HEADER = "lost: with a repeat / without any failure / after distinct failures only"
SOLVED_HEADER = "solved before any failure; solved / episodes with a failure"


def lost_table(episodes: dict[str, dict[str, Episodes]], labels: Labels | None = None) -> str:
    """Per task and method, how many episodes were lost and why (`LostEpisodes`), and how many were solved
    before any failure, where recovery plays no part (`solved_before_any_failure`)."""
    lines = [f"| task | method | {LOST_HEADER} | {SOLVED_HEADER} |", "|---|---|---|---|"]
    for task, methods in episodes.items():
        for method, runs in methods.items():
            lines.append(
                f"| {task} | {label_of(task, method, labels)} | {LostEpisodes.of(runs)} | "
                f"{solved_before_any_failure(runs)} |"
            )
    return "\n".join(lines)


def bar_chart(results: Results, path: str | Path) -> None:
    """One panel per metric, bars grouped by task, one colour per method, 95% intervals as error bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(results)
    methods = [m for m in METHOD_LABELS if any(m in results[t] for t in tasks)]
    fig, axes = plt.subplots(2, 2, figsize=(13, 7.5))
    width = 0.8 / len(methods)
    x = np.arange(len(tasks))
    for ax, name in zip(axes.flat, CHART_METRICS, strict=True):
        label = METRIC_LABELS[name]
        for k, method in enumerate(methods):
            est = [getattr(results[t][method], name) if method in results[t] else None for t in tasks]
            values = np.array([e.value if e else np.nan for e in est])
            errors = np.array([[e.value - e.low, e.high - e.value] if e else [np.nan, np.nan] for e in est]).T
            errors = np.clip(errors, 0.0, None)  # float round-off of one-valued bootstrap samples
            ax.bar(
                x + (k - (len(methods) - 1) / 2) * width,
                values,
                width,
                yerr=errors,
                capsize=2,
                label=METHOD_LABELS[method],
            )
        ax.set_title(label)
        ax.set_xticks(x, [t.removesuffix("-v0") for t in tasks], fontsize=8)
        if name != "attempts":
            ax.set_ylim(0, 1.05)
    axes.flat[0].legend(fontsize=8)
    fig.suptitle("CCDP vs DP vs DP* (95% intervals)")
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata=CHART_MARK)  # the mark that lets a later --publish replace it
    plt.close(fig)
