"""Folders this project created, told apart from everything else, so that no command deletes what it did not
create.

A folder is ours when it holds `MARKER`, recording which command made it and a digest of the path it was made
at: a digest, not the path, since a dataset pushed to the Hub uploads its marker. A copy, a download, a move
or a symlink to one of our folders is therefore not ours. Datasets (`datasets/staging.py`), the pipeline's
output folder and the benchmarks' work folders all use it: `--overwrite` and `--fresh` delete only what
`owner` recognises, never by the shape of a folder's contents.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
from pathlib import Path

MARKER = ".lerobot_ccdp_owner.json"


class NotOwned(RuntimeError):
    """A folder or file holds what this project did not put there (it is neither written into, replaced nor
    deleted), or an output cannot be made where it is named."""


def unmakeable(path: str | Path) -> tuple[int, Path, str] | None:
    """Why `path`, which does not exist, cannot be made: (errno, the nearest existing folder above it or the
    file in its way, the problem), or None when its nearest existing ancestor is a writable folder."""
    ancestor = Path(path).absolute().parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        return errno.ENOTDIR, ancestor, "a file, not a folder"
    if os.access(ancestor, os.W_OK | os.X_OK):
        return None
    if os.statvfs(ancestor).f_flag & os.ST_RDONLY:
        return errno.EROFS, ancestor, "on a read-only file system"
    return errno.EACCES, ancestor, "not writable (permission denied)"


def identity(folder: str | Path) -> str:
    """A digest of where `folder` is: its parent resolved (symlinks, `..`, relative spellings), its own name
    as given, so that a symlink named elsewhere is not the folder it points to."""
    folder = Path(folder).absolute()
    where = folder.resolve() if folder.name in ("", "..") else folder.parent.resolve() / folder.name
    return hashlib.sha256(str(where).encode()).hexdigest()


def mark(folder: str | Path, created_by: str, at: str | Path | None = None) -> None:
    """Write `folder`'s marker, naming `created_by`, for the path `at` the folder will have (default: where it
    is; a dataset is marked in its staging folder before it is renamed into place)."""
    record = {"created_by": created_by, "path_sha256": identity(folder if at is None else at)}
    (Path(folder) / MARKER).write_text(json.dumps(record, indent=2) + "\n")


def owner(folder: str | Path) -> str | None:
    """Which of this project's commands made `folder` where it is now, or None (no marker, or one of a folder
    that was copied, moved or downloaded here)."""
    try:
        record = json.loads((Path(folder) / MARKER).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("path_sha256") != identity(folder):
        return None
    return str(record.get("created_by"))


def check_output_folder(
    out: Path, created_by: str, fresh: bool = False, adopt: bool = False, flag: str = "--out"
) -> None:
    """Refuse (NotOwned) an output folder `created_by` did not make, before anything is written or deleted.

    A missing or empty folder, or one `created_by` marked where it is now, is used; `adopt` marks a folder of
    an earlier version, made before the marker. `fresh` never deletes the working directory, the home folder
    or a folder holding them, marked or not."""
    real = out.resolve()
    if fresh and any(p.is_relative_to(real) for p in (Path.cwd().resolve(), Path.home().resolve())):
        raise NotOwned(
            f"{flag} {real} is or holds the working directory or the home folder, which --fresh would "
            "delete. Nothing was deleted; choose another folder."
        )
    if real.exists() and not real.is_dir():
        raise NotOwned(f"{flag} {real} is a file, not a folder. Nothing was changed; choose another folder.")
    if not real.exists() and (problem := unmakeable(real)) is not None:
        raise NotOwned(
            f"{flag} {real} cannot be made: {problem[1]} is {problem[2]}. Nothing was changed; choose "
            "another folder."
        )
    made_by = owner(real) if real.exists() else None
    if adopt or not real.exists() or made_by == created_by or not any(real.iterdir()):
        return
    reason = (
        f"it was made by {made_by}, not by {created_by}"
        if made_by
        else f"it holds files and no {MARKER} of this folder (the mark of one {created_by} made here; "
        "a moved or copied output folder carries the mark of its old place)"
    )
    if fresh:
        advice = (
            "--fresh deletes only a folder this command made: choose another folder, or delete it yourself"
        )
    else:
        advice = (
            "Choose another folder, or, if it is an output folder of an earlier version of this command, "
            "rerun with --adopt to mark it as its own and resume it"
        )
    raise NotOwned(f"Refusing {flag} {real}: {reason}. Nothing was deleted or written. {advice}.")


def claim_output_folder(
    out: Path, created_by: str, fresh: bool = False, adopt: bool = False, flag: str = "--out"
) -> None:
    """Make `out` `created_by`'s folder, emptied with `fresh`, once `check_output_folder` allows it (checked
    again here, at the moment of change)."""
    check_output_folder(out, created_by, fresh, adopt, flag)
    real = out.resolve()
    if fresh and real.exists():
        shutil.rmtree(real)
    real.mkdir(parents=True, exist_ok=True)
    mark(real, created_by)
