"""Every eval config's seeds mean what docs/evaluation.md's "Seeds" says (`lerobot_ccdp.benchmark.rounds`)."""

import json
import re
from pathlib import Path

import pytest

from lerobot_ccdp.benchmark.rounds import (
    DEMONSTRATIONS,
    DEVELOPMENT,
    EARLY,
    FIRST_DEVELOPMENT,
    NEXT_ROUND,
    ROUNDS,
    YOURS,
    last_test,
    span,
    spent,
)

REPO = Path(__file__).resolve().parents[2]
EVAL_CONFIGS = sorted(REPO.glob("configs/*/eval.json"))


def _overlap(a: range, b: range) -> bool:
    return a.start < b.stop and b.start < a.stop


@pytest.mark.parametrize("path", EVAL_CONFIGS, ids=lambda p: p.parent.name)
def test_an_eval_config_holds_the_seeds_of_its_last_published_test(path):
    """`make benchmark*` with a shipped eval config reproduces the figures published for it: the seeds and
    size of its last test round (or of its 2000-2099 test, for the lite and camera configs that had no
    round since); a config never tested evaluates on the first development seeds, never on spent ones."""
    config = json.loads(path.read_text())
    seeds = range(config["seed"], config["seed"] + config["eval"]["n_episodes"])
    last = last_test(path.parent.name)
    expected = last.seeds if last is not None else FIRST_DEVELOPMENT
    assert seeds == expected, (
        f'{path.relative_to(REPO)} evaluates seeds {span(seeds)}; docs/evaluation.md ("Seeds") says it holds '
        f"{span(expected)}, " + (f"its last test at {last.commit}" if last else "the development seeds")
    )


def test_the_ranges_do_not_overlap_and_the_next_round_is_fresh():
    """Development, spent, yours and the next round are disjoint: a round never reuses a seed, and no
    setting is chosen on a seed a round has seen."""
    used = spent()
    for a, b in zip(used, used[1:], strict=False):
        assert a.stop <= b.start, f"{span(a)} and {span(b)} overlap"
    for seeds in used:
        for other in (DEMONSTRATIONS, DEVELOPMENT, YOURS):
            assert not _overlap(seeds, other), f"spent {span(seeds)} overlaps {span(other)}"
    assert NEXT_ROUND >= used[-1].stop and NEXT_ROUND < YOURS.start
    assert not _overlap(DEVELOPMENT, YOURS) and FIRST_DEVELOPMENT.start == DEVELOPMENT.start
    per_config: dict[str, list[range]] = {}
    for round_ in (*EARLY, *ROUNDS):
        per_config.setdefault(round_.config, []).append(round_.seeds)
    for config, ranges in per_config.items():
        assert len(set(ranges)) == len(ranges), f"{config} ran two tests on the same seeds"


def test_the_evaluation_guide_names_every_range():
    """docs/evaluation.md's "Seeds" section states the ranges this module declares, so the two cannot part."""
    text = (REPO / "docs/evaluation.md").read_text()
    section = re.search(r"^## Seeds\n(.*?)(?=^## )", text, re.S | re.M)
    assert section, 'docs/evaluation.md has no "## Seeds" section'
    body = " ".join(section.group(1).split())
    for seeds in (*spent(), FIRST_DEVELOPMENT, DEVELOPMENT, YOURS):
        assert span(seeds) in body, f'docs/evaluation.md "Seeds" does not name {span(seeds)}'
    assert f"{NEXT_ROUND} onward" in body
