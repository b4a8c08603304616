"""Atomic dataset writing: build in a hidden folder beside the target, rename into place only when complete."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
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
    finally:
        shutil.rmtree(staging, ignore_errors=True)
