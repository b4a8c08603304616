"""Which seeds are for what, and every test round run so far (docs/evaluation.md, "Seeds").

Settings are chosen on the development seeds; a test round evaluates settings frozen beforehand, once, on
seeds no setting was chosen on, and those seeds are spent with it. `python -m lerobot_ccdp.benchmark.results`
lists these rounds in docs/results.md, and `tests/benchmark/test_seeds.py` holds every `configs/*/eval.json`
and the evaluation guide to them: an eval config keeps the seeds of the last test its figures were published
from, so `make benchmark*` reproduces them; a config never tested holds the first development seeds.
"""

from __future__ import annotations

from dataclasses import dataclass

DEMONSTRATIONS = range(0, 1000)  # a recipe records its demos from `record.seed` (0) upward
DEVELOPMENT = range(1000, 1400)  # 1000-1099; 1100-1399 where 100 episodes cannot see a difference
FIRST_DEVELOPMENT = range(1000, 1100)
NEXT_ROUND = 13000  # the next declared round starts here (issue 114)
YOURS = range(50000, 60000)  # comparing methods on a checkpoint of your own; never a round of this project


def span(seeds: range) -> str:
    """A range as the docs write it, first-last."""
    return f"{seeds.start}-{seeds.stop - 1}"


@dataclass(frozen=True)
class Round:
    """One test of one config (`configs/<config>/`): its seeds, the commit it ran at, and what it missed.

    A declared round's `outcome` names each claim of issue 50 it missed, with CCDP's figure, and is empty when
    every claim was met. `declared` is False for the tests on 2000-2099, looked at after every change and not
    counted as rounds; their `outcome` says what they showed."""

    config: str
    first: int
    episodes: int
    commit: str
    outcome: str = ""
    declared: bool = True

    @property
    def seeds(self) -> range:
        return range(self.first, self.first + self.episodes)


PANDA = ("door_opening", "button_search", "object_manipulation", "object_packing", "bartender")
LITE = tuple(f"{task}_lite" for task in PANDA)
_ALL_MET = ""


def _both(first: int, episodes: int, commit: str, task: str, labelled: str, label_free: str) -> list[Round]:
    return [
        Round(task, first, episodes, commit, labelled),
        Round(f"{task}_label_free", first, episodes, commit, label_free),
    ]


EARLY = (
    # 2000-2099: the test seeds before declared rounds; results looked at after every change, hence spent.
    Round(
        "panda",
        2000,
        100,
        "b0feb82 to 3527223",
        "four runs as settings changed; the last tied DP* on "
        "every task (CCDP - DP* per run: `git show 0032ef5:docs/benchmarks.md`)",
        declared=False,
    ),
    Round(
        "panda_label_free",
        2000,
        100,
        "unknown",
        "several runs as settings changed (same record)",
        declared=False,
    ),
    *(
        Round(
            config,
            2000,
            100,
            "7b29d13",
            "CCDP above DP on four of the five, tied DP* on all (docs/benchmark_lite_report.md)",
            declared=False,
        )
        for config in LITE
    ),
    *(
        Round(config, 2000, 100, "unknown", "CCDP above DP, level with DP* (docs/cameras.md)", declared=False)
        for config in ("door_opening_lite_pixels", "button_search_lite_pixels")
    ),
)

ROUNDS = (
    # 3000-3099, frozen at 9b155a6: the set denoiser, one sample per plan, w_z 1.
    *_both(3000, 100, "a036af1", "door_opening", _ALL_MET, _ALL_MET),
    *_both(
        3000,
        100,
        "a036af1",
        "button_search",
        "non-inferiority 0.00 [-0.08, 0.08], repeats 0.05 [0.02, 0.09]",
        "non-inferiority -0.07 [-0.15, 0.01], repeats 0.23, above DP* at CCDP's cost 0.07 [-0.03, 0.17]",
    ),
    *_both(3000, 100, "a036af1", "object_manipulation", _ALL_MET, "repeats 0.04 [0.00, 0.14]"),
    *_both(
        3000,
        100,
        "a036af1",
        "object_packing",
        "non-inferiority -0.12 [-0.20, -0.03], repeats 0.07, above DP 0.06 [-0.02, 0.14], "
        "above DP* at CCDP's cost -0.06 [-0.15, 0.03]",
        "non-inferiority -0.02 [-0.10, 0.06], repeats 0.09",
    ),
    *_both(
        3000,
        100,
        "a036af1",
        "bartender",
        "non-inferiority -0.03 [-0.10, 0.04], repeats 0.33, above DP* at CCDP's cost 0.04 [-0.02, 0.10], "
        "preference -0.04 [-0.10, 0.02]",
        "all five: non-inferiority -0.06 [-0.12, -0.01], repeats 0.35, above DP 0.03 [-0.02, 0.08], "
        "above DP* at CCDP's cost -0.01 [-0.06, 0.04], preference -0.06 [-0.12, 0.00]",
    ),
    # 4000-4099, frozen at baa91c9: w_z 5 on the first 3 reverse steps.
    *_both(4000, 100, "baa91c9", "door_opening", _ALL_MET, _ALL_MET),
    *_both(4000, 100, "baa91c9", "button_search", _ALL_MET, "repeats 0.15 [0.10, 0.22]"),
    *_both(
        4000,
        100,
        "baa91c9",
        "object_manipulation",
        "non-inferiority -0.04 [-0.08, -0.01]",
        "non-inferiority -0.04 [-0.08, -0.01]",
    ),
    *_both(
        4000,
        100,
        "baa91c9",
        "object_packing",
        "non-inferiority -0.03 [-0.13, 0.07], above DP* at CCDP's cost 0.08 [-0.02, 0.18]",
        "preference -0.01 [-0.05, 0.03]",
    ),
    *_both(
        4000,
        100,
        "baa91c9",
        "bartender",
        "repeats 0.25, preference 0.01 [-0.06, 0.08]",
        "non-inferiority -0.08 [-0.14, -0.03], repeats 0.37, above DP* at CCDP's cost -0.02 [-0.06, 0.02], "
        "preference -0.04 [-0.11, 0.04]",
    ),
    # From 5000, frozen at 129e422 (label-free buttons and Bartender z in Fourier features), sized per task.
    Round("door_opening", 5000, 100, "6f2caa1"),
    Round("button_search", 5000, 100, "352fb53"),
    Round("object_manipulation", 5000, 100, "f887032"),
    Round("object_packing", 5000, 200, "93b5768"),
    Round("bartender", 5000, 300, "0e577f6", "non-inferiority -0.02 [-0.05, 0.01], repeats 0.23"),
    Round("door_opening_label_free", 5000, 100, "a50ce55"),
    Round("button_search_label_free", 5000, 100, "fe99165"),
    Round("object_manipulation_label_free", 5000, 100, "a7767e3"),
    Round("object_packing_label_free", 5000, 400, "46a754d"),
    Round("bartender_label_free", 5000, 600, "e6926b5", "repeats 0.23, preference -0.03 [-0.05, -0.00]"),
    # The Bartender: 200 demos, half after a first fill.
    *_both(6000, 600, "4c84922", "bartender", "repeats 0.15 [0.11, 0.17]", "repeats 0.11 [0.08, 0.13]"),
    Round("bartender", 7000, 600, "ddca88a", "repeats 0.15 [0.12, 0.19]"),  # failure_label_at attempt_end
    # From 8000, frozen at 77de94a: the Bartender's guard on its last 8 steps, w_z 1.
    *(round_ for task in PANDA[:3] for round_ in _both(8000, 100, "77de94a", task, _ALL_MET, _ALL_MET)),
    Round("object_packing", 8000, 200, "77de94a"),
    Round("object_packing_label_free", 8000, 400, "77de94a"),
    *_both(8000, 600, "77de94a", "bartender", "repeats 0.08 [0.06, 0.10]", "repeats 0.08 [0.06, 0.11]"),
    # The Bartender from 9000, frozen at d3c3b90: guard weight 8.
    Round("bartender", 9000, 600, "d3c3b90"),
    Round(
        "bartender_label_free",
        9000,
        600,
        "0c998a8",
        "repeats 0.07 [0.05, 0.09], preference -0.03 [-0.05, -0.00]",
    ),
    # The label-free Bartender alone.
    Round("bartender_label_free", 10000, 600, "0f9bd32", "repeats 0.09 [0.06, 0.11]"),  # base 7200 steps
    Round(  # failure sets drawn at the state, stratum weights
        "bartender_label_free",
        10600,
        600,
        "f387263",
        "repeats 0.056 [0.03, 0.08], preference -0.03 [-0.06, -0.01]",
    ),
    Round(  # 128 base draws per state
        "bartender_label_free",
        11200,
        600,
        "70be96e",
        "repeats 0.052 [0.03, 0.07], preference -0.06 [-0.08, -0.03]",
    ),
    Round(
        "bartender_label_free", 11800, 600, "83dc1ac", "repeats 0.055 [0.03, 0.08]"
    ),  # guard on the last 4 steps
    Round(
        "bartender_label_free", 12400, 600, "5a35c59"
    ),  # demonstrated rows weighed at their state, head 12000
)


@dataclass(frozen=True)
class FamilyRound:
    """A test round of the 2-D preference family: its members (not seeds), the form tested, what it showed."""

    members: range
    commit: str
    form: str
    outcome: str


FAMILY_ROUNDS = (
    FamilyRound(
        range(0, 12),
        "unknown",
        "the failure-set classifier, each / set, with and without 3 redraws",
        "issue 17's targets: failed share met with 3 redraws (0.001 / 0.003; 0.03 asked), preference "
        "error 0.064 on the mean (0.08 asked) but member 9 at 0.193 (none above 0.15 asked)",
    ),
    FamilyRound(
        range(12, 24),
        "6cd91b2",
        "the set denoiser, 3000 steps, w_z 1",
        "missed: failed share 0.016 / 0.077 (target 0.01)",
    ),
    FamilyRound(
        range(24, 36),
        "108f98c",
        "12000 steps, w_z 2 on reverse steps 5-7",
        "missed: preference error after one failure 0.053 (target 0.05)",
    ),
    FamilyRound(
        range(36, 48),
        "ebac437",
        "24000 steps, the same window",
        "missed: preference error after one failure 0.057",
    ),
    FamilyRound(
        range(48, 60),
        "efbaa1c",
        "24000 steps, w_z 1, the guard on the last 4 steps",
        "failed share met (0.000 / 0.003); preference error 0.048 / 0.036 under 0.05, not shown "
        "(intervals reach 0.062 / 0.056)",
    ),
)
NEXT_FAMILY_MEMBER = 60


def spent() -> list[range]:
    """The spent seed ranges, one per first seed: every seed any test (declared or not) has evaluated."""
    ends: dict[int, int] = {}
    for round_ in (*EARLY, *ROUNDS):
        ends[round_.first] = max(ends.get(round_.first, 0), round_.seeds.stop)
    return [range(first, ends[first]) for first in sorted(ends)]


def last_test(config: str) -> Round | None:
    """The last test a config's figures were published from: its latest declared round, else an early one."""
    for rounds in (ROUNDS, EARLY):
        runs = [r for r in rounds if r.config == config]
        if runs:
            return max(runs, key=lambda r: r.first)
    return None
