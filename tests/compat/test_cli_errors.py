"""A settings error ends lerobot-eval's output as its last line, whether this package's checks or LeRobot's
own config checks raised it under draccus's "Couldn't instantiate class ..." (compat/cli_errors.py)."""

import sys
from pathlib import Path

import pytest

import lerobot_ccdp  # noqa: F401  (installs the hook, as LeRobot's plugin discovery does)
from lerobot_ccdp.compat.cli_errors import buried_error

from fixtures.lite_eval import DOOR_LITE, run_lerobot_eval


def refused_eval(monkeypatch: pytest.MonkeyPatch, checkpoint: Path | str, *flags: str) -> BaseException:
    """What lerobot-eval's own entry point raises, in-process, for `flags` on the DoorOpening-lite env."""
    with pytest.raises(Exception) as refused:
        run_lerobot_eval(monkeypatch, checkpoint, DOOR_LITE, *flags)
    return refused.value


def last_line(error: BaseException, capsys: pytest.CaptureFixture) -> str:
    """The last line the installed sys.excepthook prints for `error` left uncaught."""
    sys.excepthook(type(error), error, error.__traceback__)
    return capsys.readouterr().err.strip().splitlines()[-1]


def test_a_policy_path_that_is_no_folder_is_named_as_missing(monkeypatch, capsys, tmp_path):
    """Before: the Hub's "Repo id must be in the form 'repo_name' or 'namespace/repo_name'" under draccus's
    "Couldn't instantiate class EvalPipelineConfig"."""
    missing = tmp_path / "runs" / "no_such_checkpoint"
    error = refused_eval(monkeypatch, missing)
    assert last_line(error, capsys) == (
        f"FileNotFoundError: Checkpoint folder {missing} does not exist (nor is it a Hub repo id): check the "
        "path, or pass the pretrained_model folder lerobot-train wrote "
        "(<output_dir>/checkpoints/last/pretrained_model)."
    )


def test_lerobots_own_config_check_ends_the_output(monkeypatch, capsys, untrained_primitive_checkpoint):
    """Before: `--eval.n_episodes=0` ended with "Couldn't instantiate class EvalConfig", LeRobot's reason 60
    lines higher."""
    error = refused_eval(monkeypatch, untrained_primitive_checkpoint, "--eval.n_episodes=0")
    assert isinstance(buried_error(error), ValueError)
    line = last_line(error, capsys)
    assert line.startswith("ValueError: The eval batch size is greater than the number of eval episodes")
    assert "eval.n_episodes=" in line
