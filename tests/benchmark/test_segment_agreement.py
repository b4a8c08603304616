"""`python -m lerobot_ccdp.benchmark.segment_agreement` in-process: it records the task's demos with
lerobot-ccdp-record and scores every rule of `demo_segments.SEGMENT_RULES` against the recorded labels."""

from lerobot_ccdp.benchmark import segment_agreement
from lerobot_ccdp.policy.demo_segments import SEGMENT_RULES


def test_an_expert_door_demo_is_one_option_so_its_episode_end_is_its_labelled_end(capsys):
    segment_agreement.main(["--tasks", "DoorOpening-lite-v0", "--episodes", "2"])
    out = capsys.readouterr().out
    assert "2 demonstrations per task" in out
    row = next(line for line in out.splitlines() if line.startswith("| DoorOpening-lite-v0 |"))
    cells = [cell.strip() for cell in row.strip("|").split("|")[1:]]
    assert len(cells) == len(SEGMENT_RULES)
    assert cells[SEGMENT_RULES.index("labels")] == "1.00 (1.0)"  # every frame, one segment per episode
