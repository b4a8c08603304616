"""What produced each pipeline stage's output, so a changed input reruns the stage and the stages after it.

A stamp hashes the stage's command line, the content of every settings file the command names (configs,
recipes), the stamp of the stage it builds on, and this package's version. Stamps are written only when a
stage completes, so a stage killed midway (a training stopped after an intermediate checkpoint) has none and
reruns.
"""

from __future__ import annotations

import hashlib
import json
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

DISTRIBUTION = "lerobot_policy_ccdp"


def settings_files(command: list[str]) -> list[Path]:
    """Files a command line names as arguments (`--config_path=x.json`, `--config_path=recipe.yaml`)."""
    values = [arg.split("=", 1)[-1] for arg in command[1:]]
    return [Path(v) for v in values if Path(v).is_file()]


def stamp(command: list[str], upstream: str | None) -> str:
    try:
        package = version(DISTRIBUTION)
    except PackageNotFoundError:
        package = "unknown"
    content = {
        "command": command,
        "files": {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in settings_files(command)},
        "upstream": upstream,
        "package": package,
    }
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:16]


class StampBook:
    """The stamps of one task's stages, in `<task out>/stamps.json`."""

    def __init__(self, path: Path):
        self.path = path
        self._stamps: dict[str, str] = json.loads(path.read_text()) if path.exists() else {}

    def matches(self, stage: str, value: str) -> bool:
        return self._stamps.get(stage) == value

    def record(self, stage: str, value: str) -> None:
        self._stamps[stage] = value
        self.path.write_text(json.dumps(self._stamps, indent=2))
