"""Rollout state that outlives one call is kept as ordinary tensors, whatever grad mode its caller runs in."""

import functools
from collections.abc import Callable
from typing import TypeVar

import torch

T = TypeVar("T", bound=Callable)


def ordinary_tensors(method: T) -> T:
    """Run `method` outside inference mode and without autograd.

    LeRobot's loops call select_action under torch.inference_mode(), while a robot's failure detector calls
    report_failure outside it; PyTorch refuses in-place updates of inference tensors outside inference mode.
    State created and updated here stays ordinary, so every mode can read and update it.
    """

    @functools.wraps(method)
    def wrapper(*args, **kwargs):
        with torch.inference_mode(False), torch.no_grad():
            return method(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
