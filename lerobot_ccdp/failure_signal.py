"""A failure signal any process can send: a file that exists means "the current attempt failed".

LeRobot's own control loops (lerobot-record --policy.path=...) only feed the policy the dataset's
features, so a robot owner's failure detector, a key handler or a teleoperator button has no way in. A
file is the smallest channel every one of them can use (`touch`), with no change to LeRobot; the policy
polls it before each observation and deletes it, so one touch is one failure.
"""

from pathlib import Path


class FailureSignalFile:
    """Polled by the policy; `poll()` is True once per creation of the file."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.parent.is_dir():
            raise ValueError(
                f"failure_signal_file={str(self.path)!r}: its folder {str(self.path.parent)!r} does not exist. "
                "Create the folder, or name a file in an existing one (e.g. /tmp/ccdp_failed)."
            )
        self.path.unlink(missing_ok=True)  # a signal left from an earlier run is not this run's failure

    def poll(self) -> bool:
        try:
            self.path.unlink()
        except FileNotFoundError:
            return False
        return True
