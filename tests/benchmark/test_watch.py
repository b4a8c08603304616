"""Which rendered episode `lerobot_ccdp.benchmark.watch` shows: the baseline repeating a failure, the other
recovering."""

import numpy as np
import pytest

from lerobot_ccdp.benchmark.episodes import Episodes
from lerobot_ccdp.benchmark.watch import pick_episode


def episodes(success, repeats, after_failure) -> Episodes:
    n = len(success)
    return Episodes(
        success=np.array(success, dtype=bool),
        attempts=np.ones(n, dtype=int),
        repeated_failures=np.array(repeats),
        preference_matched=np.ones(n, dtype=bool),
        attempts_after_failure=np.array(after_failure, dtype=float),
        failures=np.full(n, np.nan),
    )


def test_the_episode_with_most_baseline_repeats_where_the_other_method_recovered():
    dp = episodes([False, False, True, False], [2, 3, 0, 4], [2, 3, 0, 4])
    ccdp = episodes([True, True, True, False], [0, 0, 0, 0], [1, 1, 0, 1])
    assert pick_episode(dp, ccdp, [0, 1, 2, 3]) == 1  # episode 3 has more repeats but CCDP failed there
    assert pick_episode(dp, ccdp, [0, 2]) == 0  # only rendered episodes are candidates


def test_no_such_episode_is_a_clear_error():
    dp = episodes([True, True], [0, 0], [0, 0])
    ccdp = episodes([True, True], [0, 0], [0, 0])
    with pytest.raises(ValueError, match="--episode N"):
        pick_episode(dp, ccdp, [0, 1])
