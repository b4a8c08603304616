"""`python -m lerobot_ccdp.benchmark.task_stats` in-process on one geometric task: one table row with the
simulation speed, the recording time and the no-repeat oracle's figures, which solve every episode and never
repeat a failed option."""

from lerobot_ccdp.benchmark import task_stats


def test_the_no_repeat_oracle_solves_every_episode_without_a_repeat(capsys):
    task_stats.main(
        ["--tasks", "DoorOpening-lite-v0", "--steps", "20", "--record-episodes", "1"] + ["--episodes", "3"]
    )
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("| task | env steps/s | record 1 eps (s) | oracle success |")
    row = next(line for line in lines if line.startswith("| DoorOpening-lite-v0 |"))
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert float(cells[1].replace(",", "")) > 0 and float(cells[2]) > 0  # steps/s, recording seconds
    assert (cells[3], cells[6]) == ("1.000", "0.000")  # oracle success, repeated-failure rate
