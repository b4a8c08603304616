"""Paired statistics: every method runs the same seeds, so methods are compared seed by seed.

Episode i of every method starts from the same seed (same hidden parameter, same start), so the unit of
resampling is the episode index, drawn jointly for both methods (a paired bootstrap). Ratios over attempts
(repeated failures per attempt) resample whole episodes too (a cluster bootstrap): attempts of one episode
are not independent. Over several trainings (issue 114) the episodes of each training are resampled among
themselves (`strata`, a stratified bootstrap): the trainings are the ones run, not a sample drawn again, and
the spread between them is not counted as sampling noise of the episodes. A target is `met` or `missed` only
when the 95% interval of the difference lies on one side of the threshold; otherwise the methods are `not
distinguishable` at this many episodes (a tie).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from lerobot_ccdp.benchmark.episodes import Episodes, Estimate

N_RESAMPLES = 2000
Statistic = Callable[[Episodes, np.ndarray], float]  # (episodes, resampled episode indices) -> value


def success_rate(episodes: Episodes, idx: np.ndarray) -> float:
    return float(episodes.success[idx].mean())


def preference_rate(episodes: Episodes, idx: np.ndarray) -> float:
    return float(episodes.preference_matched[idx].mean())


def repeats_per_attempt(episodes: Episodes, idx: np.ndarray) -> float:
    """Repeated failures over every attempt made (the successful final attempts included)."""
    return _ratio(episodes.repeated_failures[idx].sum(), episodes.attempts[idx].sum())


def repeats_per_opportunity(episodes: Episodes, idx: np.ndarray) -> float:
    """Repeated failures over the attempts made after at least one failure: only those could repeat one."""
    return _ratio(episodes.repeated_failures[idx].sum(), episodes.attempts_after_failure[idx].sum())


def episodes_with_a_repeat(episodes: Episodes, idx: np.ndarray) -> float:
    return float((episodes.repeated_failures[idx] > 0).mean())


def _ratio(numerator: float, denominator: float) -> float:
    return float(numerator / denominator) if denominator else float("nan")


def _bootstrap(
    n: int,
    of_indices: Callable[[np.ndarray], float],
    n_resamples: int,
    seed: int,
    strata: Sequence[int] | None = None,
) -> Estimate:
    """of_indices(all episodes) with the percentile interval of of_indices over resampled episode indices.

    `strata`: the sizes of consecutive blocks of the n episodes (one training's each), each resampled among
    itself; None: one block (then the draws are those of an unstratified bootstrap)."""
    if n == 0:
        return Estimate(float("nan"), float("nan"), float("nan"), 0)
    value = of_indices(np.arange(n))
    if np.isnan(value):
        return Estimate(value, float("nan"), float("nan"), n)
    sizes = [n] if strata is None else list(strata)
    if sum(sizes) != n:
        raise ValueError(f"strata {sizes} cover {sum(sizes)} episodes, not the {n} resampled")
    rng = np.random.default_rng(seed)
    starts = np.cumsum([0, *sizes[:-1]])
    indices = np.concatenate(
        [
            start + rng.integers(0, size, size=(n_resamples, size))
            for start, size in zip(starts, sizes, strict=True)
            if size
        ],
        axis=1,
    )
    low, high = np.nanpercentile([of_indices(idx) for idx in indices], [2.5, 97.5])
    return Estimate(float(value), float(low), float(high), n)


def cluster_bootstrap(
    episodes: Episodes,
    statistic: Statistic,
    n_resamples: int = N_RESAMPLES,
    seed: int = 0,
    strata: Sequence[int] | None = None,
) -> Estimate:
    """`statistic` with a percentile interval from resampling whole episodes (within each of `strata`)."""
    return _bootstrap(len(episodes), lambda idx: statistic(episodes, idx), n_resamples, seed, strata)


def paired_difference(
    a: Episodes,
    b: Episodes,
    statistic: Statistic,
    n_resamples: int = N_RESAMPLES,
    seed: int = 0,
    strata: Sequence[int] | None = None,
) -> Estimate:
    """statistic(a) - statistic(b) with a paired-bootstrap 95% interval (episode i of both resampled
    together, within each of `strata`)."""
    if len(a) != len(b):
        raise ValueError(
            f"Paired comparison needs the same episodes (seeds) for both methods; got {len(a)} and "
            f"{len(b)}. Evaluate every method with the same eval config."
        )
    return _bootstrap(len(a), lambda idx: statistic(a, idx) - statistic(b, idx), n_resamples, seed, strata)


def seeds_for_non_inferiority(a: Episodes, b: Episodes, margin: float) -> float:
    """How many paired episodes would put the 95% interval of success(a) - success(b) above -`margin` if
    the mean and the spread of the per-seed differences stayed as measured (normal approximation): the size
    of a test round that can show non-inferiority. inf when the measured difference is at or below -margin."""
    d = a.success.astype(float) - b.success.astype(float)
    gap = d.mean() + margin
    if gap <= 0:
        return math.inf
    return float(max(1, math.ceil((1.96 * d.std(ddof=1) / gap) ** 2))) if len(d) > 1 else math.nan


def preference_difference(a: Episodes, b: Episodes, strata: Sequence[int] | None = None) -> Estimate:
    """Preference adherence of `a` minus `b` on the episodes both solved, paired (within each of `strata`): a
    method that solves more episodes is not scored on the ones only it solved, so the comparison is of
    preference, not success."""
    both = a.success & b.success
    if strata is not None:
        strata = [int(block.sum()) for block in np.split(both, np.cumsum(strata)[:-1])]
    return paired_difference(a.subset(both), b.subset(both), preference_rate, strata=strata)


def attempts_ratio(a: Episodes, b: Episodes, n_resamples: int = N_RESAMPLES, seed: int = 0) -> Estimate:
    """Mean attempts of `a` over those of `b`, on the episodes both solved, with a paired-bootstrap
    interval."""
    both = a.success & b.success
    x, y = a.attempts[both].astype(float), b.attempts[both].astype(float)
    return _bootstrap(len(x), lambda idx: x[idx].mean() / y[idx].mean(), n_resamples, seed)


def verdict(
    estimate: Estimate, low_bound: float = -np.inf, high_bound: float = np.inf, strict: bool = False
) -> str:
    """Judge a target `low_bound <= value <= high_bound` (`<` with `strict`) from the 95% interval: `met` if
    the whole interval satisfies it, `missed` if none of it does, `tie` if the interval is exactly a bound
    (every seed equal), else `not distinguishable` at this many episodes."""
    low, high = estimate.low, estimate.high
    if np.isnan(low):
        return "n/a"
    if low == high and low in (low_bound, high_bound):
        return "tie"
    if strict:
        met, missed = low > low_bound and high < high_bound, high <= low_bound or low >= high_bound
    else:
        met, missed = low >= low_bound and high <= high_bound, high < low_bound or low > high_bound
    return "met" if met else "missed" if missed else "not distinguishable"
