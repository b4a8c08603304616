"""Atomic dataset writing: build in a hidden folder beside the target, rename into place only when complete."""

from __future__ import annotations

import contextlib
import errno
import gc
import logging
import os
import shutil
import sys
import tempfile
import traceback
from collections.abc import Iterator
from pathlib import Path

logger = logging.getLogger(__name__)

STAGING_SUFFIX = ".partial"


def check_replaceable(root: str | Path, overwrite: bool) -> None:
    """Refuse, before any work, a `root` that exists unless it is a LeRobot dataset that --overwrite may replace.

    --overwrite deletes what sits at `root` once the new dataset is complete, so it must never reach a folder
    that is not a dataset: the working directory, one of its parents, or a folder of other files."""
    root = Path(root)
    if not root.exists():
        return
    if not overwrite:
        raise FileExistsError(f"{root} already exists; pass --overwrite=true to replace it, or choose another root")
    resolved, cwd = root.resolve(), Path.cwd().resolve()
    if resolved == cwd or resolved in cwd.parents:
        raise ValueError(f"--overwrite refuses {root}: it holds the working directory. Name the dataset's own folder.")
    if not (root / "meta" / "info.json").is_file():
        raise ValueError(f"--overwrite only replaces a LeRobot dataset (a folder with meta/info.json); {root} is not "
                         "one, so nothing was deleted. Choose a new path, or remove it yourself if it is yours to lose.")


def remove_stale_staging(root: Path) -> None:
    """Remove staging folders of `root` that an earlier, killed run left behind (no live process owns them)."""
    for stale in root.parent.glob(f".{root.name}.*{STAGING_SUFFIX}"):
        pid = stale.name.removeprefix(f".{root.name}.").split(".")[0]
        if pid.isdigit() and _alive(int(pid)):
            continue
        logger.info("Removing %s, left by a run that was killed", stale)
        shutil.rmtree(stale, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def staged_dataset_root(root: str | Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a fresh path to create a dataset at; when the block completes it becomes `root`.

    If the block raises (or is interrupted), nothing appears at `root` and the staging folder is removed,
    so a crashed run never leaves a half-written dataset behind; one killed outright is cleaned by the next run.
    A full disk is reported as such, naming the folder, whatever error LeRobot's writers raised last.
    """
    root = Path(root)
    check_replaceable(root, overwrite)
    root.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(root)
    staging = Path(tempfile.mkdtemp(prefix=f".{root.name}.{os.getpid()}.", suffix=STAGING_SUFFIX, dir=root.parent))
    try:
        yield staging / "dataset"
        if root.exists():
            shutil.rmtree(root)
        (staging / "dataset").rename(root)
    except BaseException as error:
        _release_frames(error)
        if any(_is_disk_full(e) for e in _chain(error)):
            raise OSError(errno.ENOSPC, f"No space left on device in {root.parent} while writing {root.name}: nothing "
                          "was written there and the partial copy is removed. Free space on that disk, or write the "
                          "dataset to another one.") from error
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _chain(error: BaseException) -> list[BaseException]:
    """`error` and the exceptions it was raised while handling."""
    chain = [error]
    while (cause := chain[-1].__cause__ or chain[-1].__context__) is not None and cause not in chain:
        chain.append(cause)
    return chain


def _is_disk_full(error: BaseException) -> bool:
    """A full disk often surfaces second-hand: a writer that failed on ENOSPC is closed by a `finally` whose own
    error ("Operation on closed file") is the one raised, so the whole chain is searched."""
    return isinstance(error, OSError) and (error.errno == errno.ENOSPC or os.strerror(errno.ENOSPC) in str(error))


def _release_frames(error: BaseException) -> None:
    """Free what the failed block's frames still hold before the staging folder is removed: a LeRobot dataset's
    destructor flushes its writers, and run later it would write a new partial folder (or fail on the full disk
    again, with a message that buries ours)."""
    hook = sys.unraisablehook
    sys.unraisablehook = lambda failed: logger.debug("A failed dataset's writer: %s", failed.exc_value)
    try:
        for link in _chain(error):
            traceback.clear_frames(link.__traceback__)
        gc.collect()
    finally:
        sys.unraisablehook = hook
