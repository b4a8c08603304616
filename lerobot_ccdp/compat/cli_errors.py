"""A settings error of this package ends the traceback of a LeRobot command, as its last line, and is what
`PreTrainedConfig.from_pretrained` raises.

LeRobot's CLIs parse their configs with draccus, which turns the ValueError a config's checks raise into
"Couldn't instantiate class CCDPConfig using the given arguments" and prints the real message 60 lines higher,
in the middle of the traceback. The hook below, installed by importing the plugin, prints the traceback as
before and then repeats that buried error as the last line. It acts only when the uncaught exception was
raised while handling a ValueError, TypeError or missing-file error from this package's own code, or a
ValueError of LeRobot's own config checks (`lerobot/configs/`: `--eval.n_episodes=0`) under draccus's
ParsingError, so a LeRobot that stops burying the message (the error is then the top exception) leaves the
output unchanged.

Through the Python API (`PreTrainedConfig.from_pretrained(folder)`, which `CCDPPolicy.from_pretrained`,
LeRobot's make_policy and `--policy.path` call) the buried error itself is raised instead of draccus's, so
that its str() names the setting; so is the reason a ccdp checkpoint's config.json names another policy type
than its fields (`checkpoint_files.mixed_config_error`), and a `--policy.path` that is neither a folder nor a
Hub repo id is named as the missing folder it is (the Hub's "Repo id must be in the form ..." before).
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path
from types import TracebackType
from typing import Any

PACKAGE = Path(__file__).resolve().parents[1]  # lerobot_ccdp, whose code raised the buried error
# The errors this package's checks raise for a setting or a path.
OURS = (ValueError, TypeError, FileNotFoundError, NotADirectoryError)


def buried_error(error: BaseException) -> BaseException | None:
    """The settings error (`OURS`) of this package's code that `error` was raised from or while handling, or
    a ValueError of LeRobot's config checks under draccus's ParsingError, if any."""
    seen, link = {id(error)}, error.__cause__ or error.__context__
    while link is not None and id(link) not in seen:
        if isinstance(link, OURS) and _raised_in(link, PACKAGE):
            return link
        if type(link) is ValueError and _raised_in(link, _lerobot_configs()) and _parsing_error(error):
            return link
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return None


def _raised_in(error: BaseException, folder: Path) -> bool:
    tb = error.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb is not None and folder in Path(tb.tb_frame.f_code.co_filename).resolve().parents


@functools.cache
def _lerobot_configs() -> Path:
    import lerobot.configs.default  # lerobot.configs is a namespace package: no __file__ of its own

    return Path(lerobot.configs.default.__file__).resolve().parent


def _parsing_error(error: BaseException) -> bool:
    """draccus's "Couldn't instantiate class ..." (checked by name: draccus is LeRobot's dependency)."""
    return type(error).__name__ == "ParsingError"


def install_error_surfacing() -> None:
    """Chain a hook after the current sys.excepthook, and wrap `PreTrainedConfig.from_pretrained`, once."""
    _surface_in_from_pretrained()
    previous = sys.excepthook
    if getattr(previous, "_ccdp_surfacing", False):
        return

    def hook(kind: type[BaseException], error: BaseException, tb: TracebackType | None) -> None:
        previous(kind, error, tb)
        buried = buried_error(error)
        if buried is not None:
            print(f"{type(buried).__name__}: {buried}", file=sys.stderr)

    hook._ccdp_surfacing = True
    sys.excepthook = hook


def _surface_in_from_pretrained() -> None:
    """Make `PreTrainedConfig.from_pretrained` read a ccdp config.json saved with settings since removed
    (`checkpoint_files.current_layout`), and raise this package's buried error, or the reason a ccdp
    config.json does not parse, in place of draccus's."""
    from lerobot.configs.policies import PreTrainedConfig

    original = PreTrainedConfig.from_pretrained.__func__
    if getattr(original, "_ccdp_surfacing", False):
        return

    @functools.wraps(original)
    def from_pretrained(cls: type, pretrained_name_or_path: str | Path, *args: Any, **kwargs: Any) -> Any:
        from lerobot_ccdp.policy.checkpoint_files import (
            HUB_DOWNLOAD_KEYS,
            current_layout,
            missing_checkpoint,
            mixed_config_error,
        )

        hub = {key: kwargs[key] for key in HUB_DOWNLOAD_KEYS if key in kwargs}
        try:
            with current_layout(pretrained_name_or_path, **hub) as path:
                return original(cls, path, *args, **kwargs)
        except Exception as error:
            clearer = (
                buried_error(error)
                or missing_checkpoint(pretrained_name_or_path)
                or mixed_config_error(pretrained_name_or_path)
            )
            if clearer is None:
                raise
            raise clearer from None

    from_pretrained._ccdp_surfacing = True
    PreTrainedConfig.from_pretrained = classmethod(from_pretrained)
