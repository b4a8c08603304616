"""A failure signal any process can send: creating or touching a file means "the current attempt failed".

LeRobot's own control loops (lerobot-record --policy.path=...) only feed the policy the dataset's
features, so a robot owner's failure detector, a key handler or a teleoperator button has no way in. A
file is the smallest channel every one of them can use (`touch`), with no change to LeRobot. The policy
polls the file's status before each observation: each time the file appears or its modification time changes
is one failure. The policy only reads the status and never deletes or writes the file: the path is the user's,
and a file that already exists when the policy starts (a signal left from an earlier run, or any file that
happens to be there) is the baseline, not a failure.
"""

from __future__ import annotations

import errno
import logging
import os
import stat
from pathlib import Path

from lerobot_ccdp.policy.configuration_ccdp import FAILURE_FLAG_KEY

logger = logging.getLogger(__name__)

# (device, inode, modification time in ns) of the file, None while absent
Status = tuple[int, int, int] | None


class FailureSignalFile:
    """Polled by the policy; `poll()` is True once per creation or touch of the file."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        setting = f"--policy.failure_signal_file={str(self.path)!r}"
        if "\0" in str(self.path):  # no file can have it: os.stat would raise "embedded null byte"
            raise ValueError(
                f"{setting} holds a NUL byte (\\x00), which no file path can contain. Name a plain path "
                "(e.g. /tmp/ccdp_failed)."
            )
        if not self.path.parent.is_dir():
            raise ValueError(
                f"{setting}: its folder {str(self.path.parent)!r} does not exist. Create the folder, or name "
                "a file in an existing one (e.g. /tmp/ccdp_failed)."
            )
        try:
            self._seen = self._status()  # what is there now is the baseline, not a failure
        except OSError as error:
            raise ValueError(
                f"{setting} cannot be used as a signal ({error.strerror}): it must be a plain file, or not "
                "exist yet, in a folder this process can read. Name another path (e.g. /tmp/ccdp_failed)."
            ) from None
        self._warned = False

    def _status(self) -> Status:
        """The file's identity and modification time, None while it is absent; OSError if it cannot be
        read."""
        try:
            info = os.stat(self.path)
        except FileNotFoundError:
            return None
        if not stat.S_ISREG(info.st_mode):
            raise IsADirectoryError(errno.EISDIR, "not a plain file")
        return info.st_dev, info.st_ino, info.st_mtime_ns

    def poll(self) -> bool:
        """Whether the file appeared or was touched since the last poll. A file that cannot be read (its
        folder lost permission, or it became a folder) is reported once and counts as no signal: the episode
        goes on."""
        try:
            current = self._status()
        except OSError as error:
            self._warn(error.strerror or str(error))
            return False
        changed = current is not None and current != self._seen
        self._seen = current
        return changed

    def _warn(self, what: str) -> None:
        if not self._warned:
            self._warned = True
            logger.warning(
                "failure_signal_file %s cannot be read (%s): no failure can be signalled through it "
                "until that is fixed.",
                self.path,
                what,
            )


def warn_nothing_reports_failures(recovery_mode: str) -> None:
    """An episode ended with recovery on and nothing that could report a failure: no env flag, no
    report_failure() call, no failure_signal_file."""
    logger.warning(
        "ccdp ran an episode with recovery_mode=%s but nothing could tell it about a failure: no %s in "
        "its inputs, no report_failure() call, no failure_signal_file. It acted as plain diffusion "
        "policy. In lerobot-record, pass --policy.failure_signal_file=/tmp/ccdp_failed and create that "
        "file when an attempt fails (docs/robot.md).",
        recovery_mode,
        FAILURE_FLAG_KEY,
    )
