"""Atomic dataset writing: build in a hidden folder beside the target, rename into place only when complete."""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def staged_dataset_root(root: str | Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a fresh path to create a dataset at; when the block completes it becomes `root`.

    If the block raises (or is interrupted), nothing appears at `root` and the staging folder is removed,
    so a crashed run never leaves a half-written dataset behind.
    """
    root = Path(root)
    if root.exists() and not overwrite:
        raise FileExistsError(f"{root} already exists; pass --overwrite to replace it or choose another --root")
    root.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{root.name}.", suffix=".partial", dir=root.parent))
    try:
        yield staging / "dataset"
        if root.exists():
            shutil.rmtree(root)
        (staging / "dataset").rename(root)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
