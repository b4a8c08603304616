"""The paper's comparison (its Fig. 5; DESIGN section 8): per task and method, metrics with 95% intervals.

Metrics, from each episode's final env info:
- success rate (Wilson interval over episodes);
- mean attempts of the successful episodes (percentile bootstrap over them); packing and bartender have two
  stages, so their minimum is 2;
- repeated-failure rate: attempts that repeat an option that already failed in the episode, over all attempts
  (Wilson interval over attempts; attempts of one episode are not independent, so read it as indicative);
- preference adherence: successful episodes whose every choice was the demonstrated preference (Wilson).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

METHOD_LABELS = {"dp": "DP", "dp_star": "DP*", "ccdp": "CCDP", "oracle": "no-repeat oracle"}
METRIC_LABELS = {
    "success": "success rate",
    "attempts": "attempts (successes)",
    "repeated_failure_rate": "repeated-failure rate",
    "preference": "preference adherence",
}
# Tasks whose demonstrations carry a preference among working options (DESIGN section 7).
PREFERENCE_TASKS = ("ObjectManipulation-v0", "ObjectPacking-v0", "Bartender-v0")
Z95 = 1.959963984540054


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its 95% interval; `n` is the number of units it is computed over."""

    value: float
    low: float
    high: float
    n: int

    def __str__(self) -> str:
        if np.isnan(self.value):
            return "n/a"
        return f"{self.value:.2f} [{self.low:.2f}, {self.high:.2f}]"


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
class Episodes:
    """Per-episode outcomes of one method on one task."""

    success: np.ndarray
    attempts: np.ndarray
    repeated_failures: np.ndarray
    preference_matched: np.ndarray

    @classmethod
    def from_infos(cls, infos: list[Mapping[str, Any]]) -> Episodes:
        """From final env infos (as the envs report them: `is_success`, `attempts`, ...)."""
        return cls(
            success=np.array([bool(i["is_success"]) for i in infos]),
            attempts=np.array([int(i["attempts"]) for i in infos]),
            repeated_failures=np.array([int(i["repeated_failures"]) for i in infos]),
            preference_matched=np.array([bool(i["preference_matched"]) for i in infos]),
        )

    @classmethod
    def from_eval_info(cls, path: str | Path) -> Episodes:
        """From the eval_info.json lerobot-eval writes (per-episode lists added by `lerobot_ccdp.eval_metrics`)."""
        info = json.loads(Path(path).read_text())
        tasks = info.get("per_task", [])
        if len(tasks) != 1:
            raise ValueError(f"{path}: expected one evaluated task, found {len(tasks)}")
        metrics = tasks[0]["metrics"]
        missing = [k for k in ("attempts", "repeated_failures", "preference_matched") if k not in metrics]
        if missing:
            raise ValueError(
                f"{path} has no per-episode {missing}: it was not written by lerobot-eval with lerobot_ccdp "
                "installed, or the env does not report them."
            )
        return cls(
            success=np.asarray(metrics["successes"], dtype=bool),
            attempts=np.asarray(metrics["attempts"], dtype=int),
            repeated_failures=np.asarray(metrics["repeated_failures"], dtype=int),
            preference_matched=np.asarray(metrics["preference_matched"], dtype=bool),
        )

    def __len__(self) -> int:
        return len(self.success)


@dataclass(frozen=True)
class MethodMetrics:
    success: Estimate
    attempts: Estimate
    repeated_failure_rate: Estimate
    preference: Estimate

    @classmethod
    def of(cls, episodes: Episodes) -> MethodMetrics:
        succeeded = episodes.success
        return cls(
            success=wilson(int(succeeded.sum()), len(episodes)),
            attempts=bootstrap_mean(episodes.attempts[succeeded]),
            repeated_failure_rate=wilson(int(episodes.repeated_failures.sum()), int(episodes.attempts.sum())),
            preference=wilson(int(episodes.preference_matched[succeeded].sum()), int(succeeded.sum())),
        )

    def as_dict(self) -> dict[str, dict[str, float]]:
        return {name: vars(getattr(self, name)) for name in METRIC_LABELS}


Results = dict[str, dict[str, MethodMetrics]]  # task -> method -> metrics


def markdown_table(results: Results) -> str:
    """One row per task and method, each metric as `value [95% interval]`."""
    lines = [
        "| task | method | episodes | " + " | ".join(METRIC_LABELS.values()) + " |",
        "|---|---|---|" + "---|" * len(METRIC_LABELS),
    ]
    for task, methods in results.items():
        for method, metrics in methods.items():
            cells = " | ".join(str(getattr(metrics, name)) for name in METRIC_LABELS)
            lines.append(f"| {task} | {METHOD_LABELS[method]} | {metrics.success.n} | {cells} |")
    return "\n".join(lines)


def target_checks(results: Results) -> str:
    """The issue's targets for CCDP, per task, with the measured margin (positive = met)."""
    rows = ["| task | target | CCDP | reference | met | margin |", "|---|---|---|---|---|---|"]

    def row(task: str, target: str, ccdp: float, reference: str, margin: float, met: bool) -> None:
        rows.append(f"| {task} | {target} | {ccdp:.3f} | {reference} | {'yes' if met else 'no'} | {margin:+.3f} |")

    for task, m in results.items():
        if "ccdp" not in m:
            continue
        ccdp = m["ccdp"]
        if "dp" in m:
            rate, dp = ccdp.repeated_failure_rate.value, m["dp"]
            row(task, "repeated-failure rate <= 0.05", rate, f"DP {dp.repeated_failure_rate.value:.3f}",
                0.05 - rate, rate <= 0.05)
            margin = ccdp.success.value - dp.success.value
            row(task, "success > DP", ccdp.success.value, f"DP {dp.success.value:.3f}", margin, margin > 0)
        if "dp_star" in m:
            star = m["dp_star"]
            margin = ccdp.success.value - star.success.value
            row(task, "success >= DP*", ccdp.success.value, f"DP* {star.success.value:.3f}", margin, margin >= 0)
            if task in PREFERENCE_TASKS:
                margin = ccdp.preference.value - star.preference.value
                row(task, "preference >= DP*", ccdp.preference.value, f"DP* {star.preference.value:.3f}",
                    margin, margin >= 0)
        if "oracle" in m:
            oracle = m["oracle"].attempts.value
            margin = 0.15 - abs(ccdp.attempts.value - oracle) / oracle
            row(task, "attempts within 15% of oracle", ccdp.attempts.value, f"oracle {oracle:.2f}", margin, margin >= 0)
    return "\n".join(rows)


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
    for ax, (name, label) in zip(axes.flat, METRIC_LABELS.items(), strict=True):
        for k, method in enumerate(methods):
            est = [getattr(results[t][method], name) if method in results[t] else None for t in tasks]
            values = np.array([e.value if e else np.nan for e in est])
            errors = np.array([[e.value - e.low, e.high - e.value] if e else [np.nan, np.nan] for e in est]).T
            errors = np.clip(errors, 0.0, None)  # float round-off of one-valued bootstrap samples
            ax.bar(x + (k - (len(methods) - 1) / 2) * width, values, width, yerr=errors, capsize=2,
                   label=METHOD_LABELS[method])
        ax.set_title(label)
        ax.set_xticks(x, [t.removesuffix("-v0") for t in tasks], fontsize=8)
        if name != "attempts":
            ax.set_ylim(0, 1.05)
    axes.flat[0].legend(fontsize=8)
    fig.suptitle("CCDP vs DP vs DP* (95% intervals)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
