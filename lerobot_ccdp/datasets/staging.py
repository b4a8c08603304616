"""Atomic dataset writing: build in a hidden folder beside the target, rename into place only when complete.

A dataset written here carries an ownership marker for the path it was written at
(`lerobot_ccdp.datasets.ownership`); `--overwrite` replaces only such a dataset at that same path, so it never
deletes what this project did not create there."""

from __future__ import annotations

import contextlib
import errno
import gc
import logging
import os
import re
import shutil
import sys
import tempfile
import traceback
from collections.abc import Iterator, Mapping
from pathlib import Path

from lerobot_ccdp.datasets.ownership import MARKER, mark, owner, unmakeable

logger = logging.getLogger(__name__)

STAGING_SUFFIX = ".partial"
# What a dataset's ownership marker says made it.
CREATED_BY = "lerobot_ccdp dataset"

# Write failures staged_dataset_root reports by the dataset's name, not the hidden staging file, with a fix.
_UNWRITABLE = "Choose a root in a folder you can write to, or fix that folder's permissions."
WRITE_FIXES = {
    errno.ENOSPC: "Free space on that disk, or write the dataset to another one.",
    errno.EDQUOT: "Free space within your disk quota, or write the dataset to another disk.",
    errno.EFBIG: "A dataset file outgrew this process's file size limit; raise it (`ulimit -f unlimited`).",
    errno.EACCES: _UNWRITABLE,
    errno.EPERM: _UNWRITABLE,
    errno.EROFS: "That file system is read-only; choose a root on a writable disk.",
    errno.ENOTDIR: "A part of that path is a file, not a folder; choose a root whose parents are folders.",
    errno.ENAMETOOLONG: "Choose a shorter root.",
}


def check_output_root(root: str | Path, overwrite: bool, overwrite_flag: str = "--overwrite=true") -> None:
    """Refuse, before any work, a `root` that cannot be created or that exists and may not be replaced.

    An empty folder (not a symlink, not the working directory) is used: the dataset takes its place.
    --overwrite (spelt `overwrite_flag` by the command) deletes what sits at `root` once the new dataset is
    complete, so it only reaches a dataset this project wrote there (`ownership.owner`): never the working
    directory, its parents, or others' files."""
    root = Path(root)
    if root.is_symlink() and not root.exists():
        raise FileExistsError(
            f"{root} is a symlink to {os.readlink(root)}, which does not exist; remove the link or choose "
            "another root"
        )
    if not root.exists():
        _check_parent_writable(root)
        return
    resolved, cwd = root.resolve(), Path.cwd().resolve()
    if resolved == cwd or resolved in cwd.parents:  # an empty root flag spells the working directory
        raise ValueError(
            f"The dataset root {root} is or holds the working directory, which the dataset would replace. "
            "Name the dataset's own folder, e.g. data/<name>."
        )
    if not root.is_symlink() and root.is_dir() and not any(root.iterdir()):
        return
    ours = owner(root) == CREATED_BY
    if not overwrite and ours:
        raise FileExistsError(
            f"{root} already exists; pass {overwrite_flag} to replace it, or choose another root"
        )
    if not overwrite:  # offering --overwrite would only lead to the refusal below
        raise FileExistsError(
            f"{root} already exists and is not a dataset lerobot_ccdp wrote at this same path (marked by "
            f"{MARKER}), so {overwrite_flag} would not replace it either. Choose a new root, or move or "
            "remove it yourself if it is yours to lose."
        )
    if not ours:
        raise ValueError(
            f"--overwrite only replaces a dataset that lerobot_ccdp wrote at this same path "
            f"(marked by {MARKER}); {root} is not one, so nothing was deleted. Choose a "
            "new root, or remove that folder yourself if it is yours to lose."
        )


def _check_parent_writable(root: Path) -> None:
    """The nearest existing folder above `root` must be writable, or the dataset cannot be created there."""
    problem = unmakeable(root)
    if problem is not None:
        code, ancestor, reason = problem
        raise OSError(code, f"Cannot create the dataset {root}: {ancestor} is {reason}. {WRITE_FIXES[code]}")


def check_disjoint(
    output: str | Path, inputs: Mapping[str, str | Path], output_flag: str = "--output.root"
) -> None:
    """Refuse an output root that is, holds or lies inside an input (`inputs`: flag -> path): replacing or
    filling it would destroy that input. Paths are compared resolved (symlinks, `..`, relative, absolute)."""
    out = Path(output).resolve()
    for flag, path in inputs.items():
        source = Path(path).resolve()
        if out == source or out in source.parents or source in out.parents:
            relation = "is" if out == source else "holds" if out in source.parents else "lies inside"
            raise ValueError(
                f"{output_flag}={output} {relation} {flag}={path} (resolved: {out} and "
                f"{source}), so writing it would destroy that input; nothing was done. Choose "
                f"an {output_flag} outside {flag}."
            )


def remove_stale_staging(root: Path) -> None:
    """Remove staging folders of `root` that an earlier, killed run left behind (no live process owns them).

    Only the names staged_dataset_root gives this very root match, `.<name>.<pid>.<random>.partial`; never
    those of another root whose name starts the same (`data` and `data.v2`)."""
    pattern = re.compile(rf"\.{re.escape(root.name)}\.(\d+)\.[^.]+{re.escape(STAGING_SUFFIX)}")
    for stale in root.parent.iterdir():
        match = pattern.fullmatch(stale.name)
        if match is None or _alive(int(match[1])):
            continue
        logger.info("Removing %s, left by a run that was killed", stale)
        shutil.rmtree(stale, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):  # OverflowError: no process has so large a pid
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def staged_dataset_root(
    root: str | Path, overwrite: bool = False, overwrite_flag: str = "--overwrite=true"
) -> Iterator[Path]:
    """Yield a fresh path to create a dataset at; when the block completes it becomes `root`, marked as ours.

    If the block raises (or is interrupted), nothing appears at `root` and the staging folder is removed,
    so a crashed run never leaves a half-written dataset behind; one killed outright is cleaned by the next.
    A write failure (full disk, permissions, file size limit) is reported naming `root` and its fix, whatever
    error LeRobot's writers raised last, rather than the hidden staging file it hit.
    """
    root = Path(root)
    check_output_root(root, overwrite, overwrite_flag)
    staging = None
    try:
        root.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_staging(root)
        staging = Path(
            tempfile.mkdtemp(prefix=f".{root.name}.{os.getpid()}.", suffix=STAGING_SUFFIX, dir=root.parent)
        )
        yield staging / "dataset"
        mark(staging / "dataset", CREATED_BY, at=root)
        check_output_root(root, overwrite, overwrite_flag)  # again: what appeared at `root` may not be ours
        if root.exists():
            root.rename(staging / "replaced")  # deleted with the staging folder, the new dataset in place
        (staging / "dataset").rename(root)
    except BaseException as error:
        _release_frames(error)
        code = _write_failure(error, root.parent)
        if code is not None:
            message = (
                f"{os.strerror(code)} in {root.parent} while writing {root.name}: nothing was written "
                f"there and the partial copy is removed. {WRITE_FIXES[code]}"
            )
            raise OSError(code, message) from error
        raise
    finally:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)


def _chain(error: BaseException) -> list[BaseException]:
    """`error` and the exceptions it was raised while handling."""
    chain = [error]
    while (cause := chain[-1].__cause__ or chain[-1].__context__) is not None and cause not in chain:
        chain.append(cause)
    return chain


def _write_failure(error: BaseException, folder: Path) -> int | None:
    """The errno of the first write failure of WRITE_FIXES in `error`'s chain, on a path in or above `folder`.

    A failure often surfaces second-hand: a writer that failed on ENOSPC is closed by a `finally` whose own
    error ("Operation on closed file") is the one raised, so the whole chain is searched. Arrow's OSErrors
    carry the cause in their text only, and no file name; one naming a file elsewhere (a device, an input)
    is not ours."""
    folder = Path(os.path.abspath(folder))
    for link in _chain(error):
        if not isinstance(link, OSError):
            continue
        if link.filename is not None:
            path = Path(os.path.abspath(os.fsdecode(link.filename)))
            if not (path.is_relative_to(folder) or folder.is_relative_to(path)):
                continue
        if link.errno in WRITE_FIXES:
            return link.errno
        for code in WRITE_FIXES:
            if os.strerror(code) in str(link):
                return code
    return None


def _release_frames(error: BaseException) -> None:
    """Free what the failed block's frames still hold before the staging folder is removed: a LeRobot
    dataset's destructor flushes its writers, and run later it would write a new partial folder (or fail on
    the full disk again, with a message that buries ours)."""
    hook = sys.unraisablehook
    sys.unraisablehook = lambda failed: logger.debug("A failed dataset's writer: %s", failed.exc_value)
    try:
        for link in _chain(error):
            traceback.clear_frames(link.__traceback__)
        gc.collect()
    finally:
        sys.unraisablehook = hook
