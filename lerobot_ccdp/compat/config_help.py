"""LeRobot's config parsing with each config class's source read once per process.

draccus builds every LeRobot CLI's parser, and parses every saved config (`PreTrainedConfig.from_pretrained`,
`TrainPipelineConfig` on `--resume`), by reading each field's help from its class's source:
`draccus.wrappers.docstring.get_attribute_docstring` calls `inspect.getsource(cls)` once per field, and on
Python 3.11 each call tokenizes the whole class again. A lerobot-train parser holds every registered
policy's, env's, optimizer's and scheduler's fields (about 900), so on the slower 2-core machine parsing took
6 of the 18 s of a ten-step `lerobot-train` run (docs/benchmarks.md, "Speed and cost").

`install_source_cache` gives draccus's docstring module a `getsource` that keeps each class's text for the
process: the same text, so the same help. Installed where that module reads source through its module-level
`inspect` (detected, not by version); elsewhere draccus runs unchanged.
"""

import functools
import inspect
from collections.abc import Callable


class _SourceOnce:
    """`inspect` as draccus's docstring module uses it, with `getsource` kept per object. A failed read
    (a class defined in `-c` code) is not kept and fails again the same way."""

    def __init__(self, getsource: Callable[[object], str] = inspect.getsource):
        self.getsource = functools.cache(getsource)

    def __getattr__(self, name: str):
        return getattr(inspect, name)


def install_source_cache() -> None:
    """Give draccus's field-help reader a source cache, once."""
    try:
        from draccus.wrappers import docstring
    except ImportError:
        return
    reads_source = callable(getattr(docstring, "get_attribute_docstring", None))
    if reads_source and getattr(docstring, "inspect", None) is inspect:
        docstring.inspect = _SourceOnce()
