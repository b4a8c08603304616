"""Decoding of `typing.Literal` config fields from the command line and from config files.

draccus 0.8, LeRobot 0.4.4's config parser, has no decoder for `Literal` and fails on any value. `choices`
gives it one where it lacks it (detected by trying, not by version), so `--policy.recovery_head=set_denoiser`
reads the same on a draccus that decodes `Literal` itself, and a value outside the choices is refused with the
choices named.
"""

from typing import Any, get_args

import draccus


def choices(literal: Any) -> tuple[str, ...]:
    """The values of the `Literal[...]` type `literal`, after making sure draccus can decode it."""
    allowed = get_args(literal)
    try:
        draccus.decode(literal, allowed[0])
    except Exception:  # draccus raises a bare Exception for a type it has no decoder for
        draccus.decode.register(literal, lambda raw: _one_of(raw, allowed))
    return allowed


def _one_of(raw: Any, allowed: tuple[str, ...]) -> str:
    if raw not in allowed:
        raise ValueError(f"{raw!r} is not one of {list(allowed)}")
    return raw
