"""The comparison's statistics and target checks on hand-made episodes."""

import numpy as np
import pytest

from lerobot_ccdp.comparison import Episodes, MethodMetrics, bootstrap_mean, markdown_table, target_checks, wilson


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


def _episodes(success, attempts, repeated, preference) -> Episodes:
    return Episodes(np.array(success), np.array(attempts), np.array(repeated), np.array(preference))


def test_metrics_count_attempts_of_successes_and_repeats_over_all_attempts():
    m = MethodMetrics.of(_episodes([True, True, False], [1, 3, 4], [0, 1, 2], [True, False, False]))
    assert m.success.value == pytest.approx(2 / 3)
    assert m.attempts.value == 2.0  # successes only
    assert m.repeated_failure_rate.value == pytest.approx(3 / 8)
    assert m.preference.value == 0.5 and m.preference.n == 2


def test_targets_report_met_and_missed_with_margins():
    good = MethodMetrics.of(_episodes([True] * 4, [2, 2, 2, 2], [0] * 4, [True] * 4))
    poor = MethodMetrics.of(_episodes([True, False, False, False], [1, 3, 3, 3], [0, 1, 1, 1], [True] + [False] * 3))
    results = {"ObjectPacking-v0": {"dp": poor, "dp_star": poor, "ccdp": good, "oracle": good}}
    checks = target_checks(results)
    assert "| ObjectPacking-v0 | success > DP | 1.000 | DP 0.250 | yes | +0.750 |" in checks
    assert "| ObjectPacking-v0 | preference >= DP* | 1.000 | DP* 1.000 | yes | +0.000 |" in checks
    assert "| ObjectPacking-v0 | attempts within 15% of oracle | 2.000 | oracle 2.00 | yes | +0.150 |" in checks
    swapped = target_checks({"ObjectPacking-v0": {"dp": good, "ccdp": poor}})
    assert "| ObjectPacking-v0 | repeated-failure rate <= 0.05 | 0.300 | DP 0.000 | no | -0.250 |" in swapped
    assert "| ObjectPacking-v0 | CCDP | 4 | 0.25 [" in markdown_table({"ObjectPacking-v0": {"ccdp": poor}})
