"""Recipe files (`datasets_recipes/<task>.yaml`): one top-level section per job; each job reads only its own.

The `record:` section (demo recording) is parsed here; other sections (e.g. `recovery:`) belong to other jobs
and are ignored by this loader.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from lerobot_ccdp.envs.base import CONTROL_FPS
from lerobot_ccdp.envs.tasks import task_class


def read_recipe_section(path: str | Path, section: str) -> dict[str, Any]:
    """The mapping under top-level key `section` of the YAML recipe at `path`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"Recipe file not found: {path}")
    content = yaml.safe_load(path.read_text())
    if not isinstance(content, dict) or section not in content:
        raise ValueError(f"Recipe {path} has no top-level `{section}:` section")
    if not isinstance(content[section], dict):
        raise ValueError(f"Recipe {path}: `{section}:` must be a mapping")
    return content[section]


@dataclass(frozen=True)
class RecordRecipe:
    """What `lerobot-ccdp-record` records: `n_episodes` expert successes of `task`, seeds from `seed` on."""

    task: str
    n_episodes: int
    seed: int
    fps: int = CONTROL_FPS
    max_episode_steps: int | None = None  # default: the task's own step limit
    task_description: str | None = None  # default: the task's own description
    env_kwargs: dict[str, Any] = field(default_factory=dict)  # extra keyword arguments of the env

    @classmethod
    def from_dict(cls, values: dict[str, Any], source: str = "recipe") -> RecordRecipe:
        known = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ValueError(f"{source}: unknown field(s) in `record:`: {', '.join(unknown)}; known: {', '.join(known)}")
        required = [n for n, f in known.items() if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
        missing = [n for n in required if n not in values]
        if missing:
            raise ValueError(f"{source}: `record:` is missing required field(s): {', '.join(missing)}")
        recipe = cls(**values)
        task_class(recipe.task)  # names the known tasks if this one is not
        if not isinstance(recipe.n_episodes, int) or recipe.n_episodes < 1:
            raise ValueError(f"{source}: record.n_episodes must be a positive integer, got {recipe.n_episodes!r}")
        if recipe.fps != CONTROL_FPS:
            raise ValueError(f"{source}: record.fps must be {CONTROL_FPS} (the tasks' control rate), got {recipe.fps}")
        return recipe

    @classmethod
    def load(cls, path: str | Path) -> RecordRecipe:
        return cls.from_dict(read_recipe_section(path, "record"), source=str(path))

    def with_episodes(self, n_episodes: int | None) -> RecordRecipe:
        if n_episodes is None:
            return self
        return self.from_dict({**dataclasses.asdict(self), "n_episodes": n_episodes}, source="override")
