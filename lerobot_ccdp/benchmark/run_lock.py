"""One pipeline per output folder, and no stage outliving the pipeline that started it.

Two pipelines on one folder would train into the same checkpoints; a stage left running after its pipeline was
killed (kill -9 reaches no handler) would keep writing there while a rerun starts over it.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import re
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from lerobot_ccdp.datasets.ownership import NotOwned

PR_SET_PDEATHSIG = 1


class PipelineRunning(RuntimeError):
    """Another pipeline holds the output folder."""


@contextlib.contextmanager
def exclusive(out: Path) -> Iterator[None]:
    """Hold the lock of output folder `out` while running: a file beside it (so --fresh may delete the
    folder), named after its real path (every spelling of the folder takes one lock), removed when it ends."""
    out = out.resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    path = out.parent / f".{out.name}.pipeline.lock"
    handle = _locked(path, out)
    handle.seek(0)
    if not re.fullmatch(r"\d*\s*", handle.read()):  # a killed run's lock holds its pid, a new one nothing
        handle.close()
        raise NotOwned(
            f"{path}, the lock file of --out {out}, holds something other than a pipeline's pid: "
            "lerobot_ccdp did not write it. Nothing was written. Move or delete it yourself, or choose "
            "another --out."
        )
    try:
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        yield
    finally:
        path.unlink(missing_ok=True)  # while still locked: no other run holds a lock on this file now
        handle.close()  # releases the lock


def _locked(path: Path, out: Path) -> IO[str]:
    """`path` opened and locked. A run that ends removes its lock file: one that opened the file before it was
    removed and locked it after locks a file no longer at `path`, and retries on the file there now."""
    while True:
        handle = path.open("a+")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            pid = handle.read().strip() or "unknown"
            handle.close()
            raise PipelineRunning(
                f"Another pipeline (pid {pid}) is running on {out}: wait for it to finish, or stop "
                f"it (kill {pid}) before starting this one."
            ) from None
        with contextlib.suppress(FileNotFoundError):
            if os.path.samestat(os.fstat(handle.fileno()), os.stat(path)):
                return handle
        handle.close()


def die_with_parent(parent: int) -> None:
    """`preexec_fn` of a stage (bind `parent`, the pipeline's pid): the kernel kills it when the pipeline
    process dies, however it dies (Linux). A pipeline that died before the signal was armed is caught by the
    parent check."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:
        os.kill(os.getpid(), signal.SIGKILL)
