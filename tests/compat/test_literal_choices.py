"""`Literal` config fields parse from LeRobot's command line and checkpoints, and a value outside them is
named."""

from dataclasses import dataclass
from typing import Literal

import draccus
import pytest
from lerobot.configs.policies import PreTrainedConfig

import lerobot_ccdp  # noqa: F401  (registers the ccdp policy type)
from lerobot_ccdp.compat.literal_choices import choices


@dataclass
class Command:
    """The `--policy.*` part of a LeRobot command line, as lerobot-train and lerobot-eval parse it."""

    policy: PreTrainedConfig | None = None


def test_a_literal_field_parses_from_the_command_line_and_back_from_a_saved_checkpoint(tmp_path):
    parsed = draccus.parse(
        Command,
        args=[
            "--policy.type=ccdp",
            "--policy.recovery_head=set_denoiser",
            "--policy.failure_segments=drops",
            "--policy.device=cpu",
        ],
    ).policy
    assert (parsed.recovery_head, parsed.failure_segments) == ("set_denoiser", "drops")
    parsed._save_pretrained(tmp_path)
    loaded = PreTrainedConfig.from_pretrained(tmp_path, cli_overrides=["--recovery_mode=dp_star"])
    assert (loaded.recovery_head, loaded.recovery_mode) == ("set_denoiser", "dp_star")


def test_a_value_outside_the_choices_is_refused_naming_them():
    with pytest.raises(
        draccus.utils.DecodingError,
        match=r"'mlp' is not one of \['auto', 'unet', 'classifier', 'set_denoiser'\]",
    ):
        draccus.parse(Command, args=["--policy.type=ccdp", "--policy.recovery_head=mlp"])


def test_choices_gives_draccus_a_decoder_for_a_new_literal_type():
    mode = Literal["left", "right"]
    assert choices(mode) == ("left", "right")
    assert draccus.decode(mode, "right") == "right"
    with pytest.raises(Exception, match=r"'up' is not one of \['left', 'right'\]"):
        draccus.decode(mode, "up")


def test_the_head_left_out_is_auto_for_the_features_to_name():
    parsed = draccus.parse(Command, args=["--policy.type=ccdp", "--policy.device=cpu"]).policy
    assert parsed.recovery_head == "auto"
