"""Per-episode outcomes of an evaluation, and an estimate with its interval: what the statistics work on."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np


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


@dataclass(frozen=True)
class Episodes:
    """Per-episode outcomes of one method on one task."""

    success: np.ndarray
    attempts: np.ndarray
    repeated_failures: np.ndarray
    preference_matched: np.ndarray
    attempts_after_failure: np.ndarray  # NaN where the run predates the metric
    failures: np.ndarray  # failed attempts; NaN where the run predates the metric

    @classmethod
    def from_infos(cls, infos: list[Mapping[str, Any]]) -> Episodes:
        """From final env infos (as the envs report them: `is_success`, `attempts`, ...)."""
        return cls(
            success=np.array([bool(i["is_success"]) for i in infos]),
            attempts=np.array([int(i["attempts"]) for i in infos]),
            repeated_failures=np.array([int(i["repeated_failures"]) for i in infos]),
            preference_matched=np.array([bool(i["preference_matched"]) for i in infos]),
            attempts_after_failure=np.array([float(i.get("attempts_after_failure", np.nan)) for i in infos]),
            failures=np.array([float(i.get("failures", np.nan)) for i in infos]),
        )

    @classmethod
    def from_eval_info(cls, path: str | Path) -> Episodes:
        """From the eval_info.json lerobot-eval writes (per-episode lists added by
        `lerobot_ccdp.compat.eval_metrics`)."""
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
            attempts_after_failure=np.asarray(
                metrics.get("attempts_after_failure", [np.nan] * len(metrics["successes"])), dtype=float
            ),
            failures=np.asarray(metrics.get("failures", [np.nan] * len(metrics["successes"])), dtype=float),
        )

    @classmethod
    def concatenate(cls, parts: list[Episodes]) -> Episodes:
        """Several runs' episodes as one run (several tasks' development seeds, pooled for one choice)."""
        return cls(**{name: np.concatenate([vars(part)[name] for part in parts]) for name in vars(parts[0])})

    def subset(self, mask: np.ndarray) -> Episodes:
        """The episodes where `mask` is true, in order (for paired comparisons on a common subset)."""
        return Episodes(**{name: value[mask] for name, value in vars(self).items()})

    def __len__(self) -> int:
        return len(self.success)


@dataclass(frozen=True)
class LostEpisodes:
    """Why the unsuccessful episodes of a run were lost, which says whether recovery or execution costs
    success: `with_repeat` repeated a failed option (what recovery should prevent); `without_failure` ended
    before any attempt failed (the policy never completed one: an execution problem that no failure memory can
    fix); `distinct_failures` failed only different options and ran out of time or of allowed failures."""

    lost: int
    with_repeat: int
    without_failure: int | None  # None where the run predates the per-episode failure count
    distinct_failures: int | None

    @classmethod
    def of(cls, episodes: Episodes) -> LostEpisodes:
        lost = ~episodes.success
        repeat = lost & (episodes.repeated_failures > 0)
        if np.isnan(episodes.failures).any():
            return cls(int(lost.sum()), int(repeat.sum()), None, None)
        none = lost & (episodes.failures == 0)
        return cls(int(lost.sum()), int(repeat.sum()), int(none.sum()), int((lost & ~repeat & ~none).sum()))

    def __str__(self) -> str:
        if self.without_failure is None:
            return f"{self.lost}: {self.with_repeat} / n/a / n/a"
        return f"{self.lost}: {self.with_repeat} / {self.without_failure} / {self.distinct_failures}"


def solved_before_any_failure(episodes: Episodes) -> str:
    """Episodes solved without a failed attempt, and `solved / had` of those where an attempt failed:
    "45; 38 / 55".

    Until an episode's first failure DP, DP* and CCDP sample the same base policy: with common random numbers
    (`samplers.row_generators`) the first count matches between them, without them it differs by sampling
    luck alone; recovery shows in the second. "n/a" where the run predates the failure count.
    """
    if np.isnan(episodes.failures).any():
        return "n/a"
    failed = episodes.failures > 0
    return (
        f"{int((episodes.success & ~failed).sum())}; "
        f"{int((episodes.success & failed).sum())} / {int(failed.sum())}"
    )
