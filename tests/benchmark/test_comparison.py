"""The comparison's statistics and target checks on hand-made episodes."""

import numpy as np
import pytest

from lerobot_ccdp.benchmark.comparison import (
    Episodes,
    MethodMetrics,
    bootstrap_mean,
    lost_table,
    markdown_table,
    wilson,
)
from lerobot_ccdp.benchmark.episodes import Estimate, LostEpisodes, solved_before_any_failure
from lerobot_ccdp.benchmark.paired import (
    cluster_bootstrap,
    paired_difference,
    repeats_per_attempt,
    success_rate,
    verdict,
)
from lerobot_ccdp.benchmark.targets import target_checks


def test_wilson_matches_published_values_and_stays_in_unit_interval():
    half = wilson(5, 10)
    assert (half.low, half.high) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    none = wilson(0, 10)
    assert none.value == 0.0 and none.low == 0.0 and none.high == pytest.approx(0.2775, abs=1e-4)
    assert wilson(10, 10).high == 1.0
    assert np.isnan(wilson(0, 0).value)


def test_bootstrap_interval_contains_the_mean_and_is_reproducible():
    values = np.array([1, 1, 2, 2, 3, 4])
    first, second = bootstrap_mean(values), bootstrap_mean(values)
    assert first == second and first.low < values.mean() < first.high and first.n == 6


def _episodes(success, attempts, repeated, preference, after_failure=None, failures=None) -> Episodes:
    """Episodes; attempts after a failure and failures default to what a one-stage task gives: attempts - 1 if
    any failed, and every attempt but a success."""
    attempts, success = np.array(attempts), np.array(success)
    if after_failure is None:
        after_failure = np.where(attempts > np.array(success, dtype=int), attempts - 1, 0)
    if failures is None:
        failures = attempts - np.array(success, dtype=int)
    return Episodes(
        success,
        attempts,
        np.array(repeated),
        np.array(preference),
        np.array(after_failure, dtype=float),
        np.array(failures, dtype=float),
    )


def test_lost_episodes_are_split_by_repeat_no_failure_and_distinct_failures():
    # Lost: one repeated a failure, one never had an attempt fail (time ran out), two failed distinct options
    # only.
    runs = _episodes(
        [True, False, False, False, False],
        [2, 3, 0, 2, 1],
        [0, 1, 0, 0, 0],
        [True] + [False] * 4,
        failures=[1, 3, 0, 2, 1],
    )
    lost = LostEpisodes.of(runs)
    assert (lost.lost, lost.with_repeat, lost.without_failure, lost.distinct_failures) == (4, 1, 1, 2)
    assert str(lost) == "4: 1 / 1 / 2"
    # no failure count
    older = _episodes([False, False], [1, 2], [0, 1], [False, False], failures=[np.nan, np.nan])
    assert str(LostEpisodes.of(older)) == "2: 1 / n/a / n/a"


def test_metrics_count_attempts_of_successes_and_repeats_over_all_attempts():
    m = MethodMetrics.of(_episodes([True, True, False], [1, 3, 4], [0, 1, 2], [True, False, False]))
    assert m.success.value == pytest.approx(2 / 3)
    assert m.attempts.value == 2.0  # successes only
    assert m.repeated_failure_rate.value == pytest.approx(3 / 8)
    assert m.preference.value == 0.5 and m.preference.n == 2


def test_repeat_rates_per_attempt_per_opportunity_and_per_episode():
    # Episode 1: failed, repeated it, then succeeded (3 attempts, 2 after a failure); episode 2: first try.
    m = MethodMetrics.of(_episodes([True, True], [3, 1], [1, 0], [True, True], after_failure=[2, 0]))
    assert m.repeated_failure_rate.value == pytest.approx(1 / 4)  # the paper's: successes in the denominator
    assert m.repeats_per_opportunity.value == pytest.approx(1 / 2)  # only attempts that could repeat
    assert m.episodes_with_repeat.value == pytest.approx(1 / 2)


def test_paired_difference_of_identical_runs_is_an_exact_tie():
    same = _episodes([True, False] * 10, [1, 3] * 10, [0, 1] * 10, [True, False] * 10)
    diff = paired_difference(same, same, success_rate)
    assert (diff.value, diff.low, diff.high) == (0.0, 0.0, 0.0)
    assert verdict(diff, low_bound=0.0, strict=True) == "tie" and verdict(diff, low_bound=0.0) == "tie"


def test_paired_difference_of_all_different_seeds_is_certain():
    wins = _episodes([True] * 20, [1] * 20, [0] * 20, [True] * 20)
    losses = _episodes([False] * 20, [3] * 20, [2] * 20, [False] * 20)
    diff = paired_difference(wins, losses, success_rate)
    assert (diff.value, diff.low, diff.high) == (1.0, 1.0, 1.0)
    assert verdict(diff, low_bound=0.0, strict=True) == "met"
    assert verdict(paired_difference(losses, wins, success_rate), low_bound=0.0) == "missed"


def test_pairing_narrows_the_interval_of_correlated_runs():
    """Seeds that are hard for both methods cancel out in the paired difference, not in separate intervals."""
    rng = np.random.default_rng(0)
    hard = rng.random(100) < 0.5
    a = _episodes(~hard | (rng.random(100) < 0.2), [1] * 100, [0] * 100, [True] * 100)
    b = _episodes(~hard, [1] * 100, [0] * 100, [True] * 100)  # a solves every seed b does, and some more
    diff = paired_difference(a, b, success_rate)
    hand = a.success.mean() - b.success.mean()
    assert diff.value == pytest.approx(hand) and diff.low >= 0.0  # a never does worse on a seed
    separate = wilson(int(a.success.sum()), 100).low - wilson(int(b.success.sum()), 100).high
    assert separate < 0 < diff.low or diff.low == 0.0  # unpaired intervals overlap; the paired one does not


def test_cluster_bootstrap_resamples_episodes_not_attempts():
    # Ten episodes, one with 9 repeats of 10 attempts: the per-attempt rate is driven by one episode, and
    # resampling episodes (not attempts) shows that uncertainty.
    episodes = _episodes([True] * 10, [10] + [1] * 9, [9] + [0] * 9, [True] * 10)
    estimate = cluster_bootstrap(episodes, repeats_per_attempt)
    assert estimate.value == pytest.approx(9 / 19)
    assert estimate.low == 0.0 and estimate.high > 0.6


def test_verdicts_name_met_missed_and_not_distinguishable():
    assert verdict(Estimate(0.1, 0.02, 0.2, 100), low_bound=0.0, strict=True) == "met"
    assert verdict(Estimate(0.0, -0.05, 0.06, 100), low_bound=0.0, strict=True) == "not distinguishable"
    assert verdict(Estimate(-0.2, -0.3, -0.1, 100), low_bound=0.0) == "missed"
    assert verdict(Estimate(0.03, 0.01, 0.049, 100), high_bound=0.05) == "met"
    assert verdict(Estimate(0.9, 0.8, 1.2, 50), low_bound=0.85, high_bound=1.15) == "not distinguishable"


def test_targets_table_judges_from_paired_intervals():
    good = _episodes([True] * 40, [2] * 40, [0] * 40, [True] * 40)
    poor = _episodes(
        [True] * 10 + [False] * 30, [1] * 10 + [3] * 30, [0] * 10 + [1] * 30, [True] * 10 + [False] * 30
    )
    checks = target_checks(
        {
            "ObjectPacking-lite-v0": {
                "dp": poor,
                "dp_star": good,
                "dp_star_matched": poor,
                "ccdp": good,
                "oracle": good,
            }
        }
    )
    assert "| ObjectPacking-lite-v0 | success > DP | CCDP - DP 0.75 [0.60, 0.88] | met |" in checks
    # Non-inferiority to DP* (issue 50): the interval's low end above -0.05; every seed equal meets it.
    assert (
        "| ObjectPacking-lite-v0 | success non-inferior to DP* (margin 0.05) "
        "| CCDP - DP* 0.00 [0.00, 0.00] | met |" in checks
    )
    assert "| success > DP* at CCDP's cost | CCDP - DP* at CCDP's cost 0.75 [0.60, 0.88] | met |" in checks
    slightly_worse = _episodes([True] * 39 + [False], [2] * 39 + [3], [0] * 40, [True] * 39 + [False])
    behind = target_checks({"ObjectPacking-lite-v0": {"dp_star": good, "ccdp": slightly_worse}})
    assert "CCDP - DP* -0.03 [-0.07, 0.00] | not distinguishable |" in behind
    assert (
        "| ObjectPacking-lite-v0 | preference >= DP* (episodes both solved) "
        "| CCDP - DP* 0.00 [0.00, 0.00] | tie |" in checks
    )
    assert (
        "| ObjectPacking-lite-v0 | repeated-failure rate <= 0.05 | CCDP rate 0.00 [0.00, 0.00] | met |"
        in checks
    )
    swapped = target_checks({"ObjectPacking-lite-v0": {"dp": good, "ccdp": poor}})
    assert "success > DP | CCDP - DP -0.75 [" in swapped and "| missed |" in swapped
    assert "| ObjectPacking-lite-v0 | CCDP | 40 | 0.25 [" in markdown_table(
        {"ObjectPacking-lite-v0": {"ccdp": MethodMetrics.of(poor)}}
    )


def test_solved_before_any_failure_splits_wins_by_whether_recovery_played_a_part():
    # Solved: two without a failure, one after a failure; lost: one after a failure, one without any.
    runs = _episodes(
        [True, True, True, False, False],
        [1, 1, 2, 3, 0],
        [0, 0, 0, 1, 0],
        [True] * 3 + [False] * 2,
        failures=[0, 0, 1, 2, 0],
    )
    assert solved_before_any_failure(runs) == "2; 1 / 2"
    table = lost_table({"Task-v0": {"ccdp": runs}})
    assert table.splitlines()[-1] == "| Task-v0 | CCDP | 2: 1 / 1 / 0 | 2; 1 / 2 |"
    older = _episodes([True, False], [1, 2], [0, 1], [True, False], failures=[np.nan, np.nan])
    assert solved_before_any_failure(older) == "n/a"
