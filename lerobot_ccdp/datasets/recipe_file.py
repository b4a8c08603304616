"""Recipe files (`datasets_recipes/<task>.yaml`): one top-level section per job; each job reads only its own.

`record:` holds what `lerobot-ccdp-record` records, `recovery:` how `lerobot-ccdp-synthesize` builds the
recovery dataset (paper eq. 5-7). The CLIs (`datasets/configs.py`) build these dataclasses from the file's
section merged with `--record.<field>` / `--recovery.<field>` flags through `from_dict`, so a value is checked
the same way wherever it comes from.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from lerobot_ccdp.envs.interface import CONTROL_FPS
from lerobot_ccdp.envs.tasks import task_class
from lerobot_ccdp.policy.configuration_ccdp import FAILURE_FEATURES


def read_recipe_section(path: str | Path, section: str) -> dict[str, Any]:
    """The mapping under top-level key `section` of the YAML recipe at `path`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"Recipe file not found: {path}")
    try:
        content = yaml.safe_load(path.read_text())
    except yaml.YAMLError as error:
        raise ValueError(f"Recipe {path} is not valid YAML: {error}") from None
    if not isinstance(content, dict) or section not in content:
        raise ValueError(f"Recipe {path} has no top-level `{section}:` section")
    if not isinstance(content[section], dict):
        raise ValueError(f"Recipe {path}: `{section}:` must be a mapping")
    return content[section]


@dataclass(frozen=True)
class RecordRecipe:
    """What `lerobot-ccdp-record` records: `n_episodes` expert successes of `task`, seeds from `seed` on."""

    task: str  # required: a task of docs/tasks.md, e.g. DoorOpening-v0
    n_episodes: int  # required: successful expert episodes to keep (failed ones are discarded)
    seed: int  # required: seed of the first episode; each next attempt takes the next seed
    fps: int = CONTROL_FPS  # the tasks' control rate; no other value is accepted
    max_episode_steps: int | None = None  # step limit of an episode; null: the task's own
    task_description: str | None = None  # the dataset's task text; null: the task's own description
    # extra env arguments, e.g. {obs_type: pixels_agent_pos}
    env_kwargs: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, values: dict[str, Any], source: str | None = None) -> RecordRecipe:
        """The recipe of a `record:` mapping, checked; errors start with `source` (the file) where given."""
        at = f"{source}: " if source else ""
        recipe = _build(cls, values, "record", at)
        env_class = task_class(recipe.task)  # names the known tasks if this one is not
        for name in ("n_episodes", "max_episode_steps"):
            if (value := getattr(recipe, name)) is not None and value < 1:
                raise ValueError(f"{at}record.{name} must be a positive integer, got {value!r}")
        if recipe.seed < 0:
            raise ValueError(f"{at}record.seed must be >= 0 (gymnasium's seeds), got {recipe.seed}")
        accepted = env_arguments(env_class)
        unknown = sorted(set(recipe.env_kwargs) - set(accepted))
        if unknown:
            raise ValueError(
                f"{at}record.env_kwargs: {recipe.task} takes no argument(s) "
                f"{', '.join(unknown)}; it accepts {', '.join(accepted)} (the step limit is "
                "record.max_episode_steps)"
            )
        if recipe.env_kwargs.get("render_mode") not in (None, "rgb_array"):  # gymnasium opens a window
            raise ValueError(
                f"{at}record.env_kwargs.render_mode={recipe.env_kwargs['render_mode']!r}: the recorder "
                "renders nothing (cameras are recorded with obs_type: pixels_agent_pos); leave it out"
            )
        for name, value in recipe.env_kwargs.items():
            if not _has_type(value, accepted[name]):
                raise ValueError(
                    f"{at}record.env_kwargs.{name} must be {_type_name(accepted[name])}, got {value!r} "
                    f"({type(value).__name__}); write it without quotes, and without decimals where a whole "
                    "number is meant (YAML reads 1e9 as text: write 1.0e+9)"
                )
        if recipe.fps != CONTROL_FPS:
            raise ValueError(
                f"{at}record.fps must be {CONTROL_FPS} (the tasks' control rate), got {recipe.fps}"
            )
        return recipe

    @classmethod
    def load(cls, path: str | Path) -> RecordRecipe:
        return cls.from_dict(read_recipe_section(path, "record"), source=str(path))


@dataclass(frozen=True)
class RecoveryRecipe:
    """How `lerobot-ccdp-synthesize` builds a recovery dataset (paper eq. 5-7).

    The failure feature settings (`Z_FIELDS`) define z, so they are those the base checkpoint was trained
    with: left null they are read from the checkpoint, and a value given must equal the checkpoint's (a
    recipe written for one base is refused for another). `delta_z` left null is the checkpoint's too (the
    distance under which the policy takes an outcome for a repeat). The other fields are the synthesis
    parameters, so a recipe with no field at all serves any base. Distances are in the policy's normalised
    space.
    """

    # z settings, as --policy.<name>; null: the base checkpoint's.
    failure_feature: str | None = None  # what z is, one of final_state, action, primitive
    failure_state_dims: list[int] | None = None  # final_state z: which dims of the state frame; []: all
    primitive_key: str | None = None  # primitive z: the dataset column of the option label
    num_primitives: int | None = None  # primitive z: the number of options (z is one-hot)
    # The defaults are the five Panda tasks' synthesis as benchmarked (docs/synthesis.md, "Why these values").
    n_states: int = 2048  # demo states x_s drawn (eq. 6); 0 = pairs from the demos only
    chunks_per_state: int = 16  # chunks sampled around each x_s from eq. (7)
    sigma: float = 0.04  # std of the state noise xi_x (eq. 6)
    w_s: float = 1.0  # state weight of eq. (7); < 1 widens the proposals (jagged chunks on a CPU-sized base)
    # drop sampled chunks whose RMS gap to every demonstrated chunk exceeds this; 0 keeps all
    outcome_radius: float = 0.0
    demo_frames: int = 4096  # demonstrated chunks that join the pool; 0 = synthesised chunks only
    # set denoiser: give a demonstrated chunk the siblings of a state drawn at its frame (`sibling_outcomes`)
    demo_siblings: bool = False
    # eq. (5): a recovery's z differs from the failure's by more than this; null: the checkpoint's delta_z
    delta_z: float | None = None
    # eq. (5): ... and its state from the failure's by less than this; 100 admits every normalised state
    delta_x: float = 100.0
    pairs_per_failure: int = 2  # recoveries drawn per pool sample taken as a failure
    batch_states: int = 32  # states sampled per batched denoising call
    seed: int = 0  # seed of every random draw (states, noise, pairs)

    @classmethod
    def from_dict(cls, values: dict[str, Any], source: str | None = None) -> RecoveryRecipe:
        """The recipe of a `recovery:` mapping, checked; errors start with `source` (the file) where given."""
        at = f"{source}: " if source else ""
        recipe = _build(cls, values, "recovery", at)
        if recipe.failure_feature not in (None, *FAILURE_FEATURES):
            raise ValueError(
                f"{at}recovery.failure_feature must be one of {list(FAILURE_FEATURES)}, "
                f"got {recipe.failure_feature!r}"
            )
        if not 0.0 < recipe.w_s <= 1.0:
            raise ValueError(f"{at}recovery.w_s must be in (0, 1] (eq. 7), got {recipe.w_s}")
        counts = ("chunks_per_state", "pairs_per_failure", "batch_states")
        bad = [name for name in counts if getattr(recipe, name) < 1] + [
            name
            for name in ("n_states", "demo_frames", "sigma", "delta_z", "delta_x", "outcome_radius")
            if (getattr(recipe, name) or 0) < 0
        ]
        if bad:
            raise ValueError(
                f"{at}recovery field(s) {', '.join(bad)} out of range (counts >= 1, the rest >= 0)"
            )
        if recipe.n_states == 0 and recipe.demo_frames == 0:
            raise ValueError(f"{at}recovery.n_states and recovery.demo_frames are both 0: the pool is empty")
        return recipe

    @classmethod
    def load(cls, path: str | Path) -> RecoveryRecipe:
        return cls.from_dict(read_recipe_section(path, "recovery"), source=str(path))

    def failure_settings(self) -> dict[str, Any]:
        """The z settings this recipe names (`failure_feature` and those its kind of z reads; null ones
        excluded), named as in CCDPConfig (`--policy.<name>`)."""
        names = ["failure_feature", *Z_FIELDS_OF.get(self.failure_feature, Z_FIELDS[1:])]
        return {name: value for name in names if (value := getattr(self, name)) is not None}

    def for_checkpoint(self, config: Any, source: str) -> RecoveryRecipe:
        """This recipe with every z setting the checkpoint's `config` (a CCDPConfig) was trained with, and its
        `delta_z` where the recipe gives none; a z setting the recipe names differently from the checkpoint is
        refused, naming both fixes."""
        wanted = self.failure_settings()
        mismatched = {k: (v, getattr(config, k)) for k, v in wanted.items() if getattr(config, k) != v}
        if mismatched:
            details = ", ".join(f"{k}: recipe {v!r} vs checkpoint {c!r}" for k, (v, c) in mismatched.items())
            flags = " ".join(f"--policy.{k}={v}" for k, v in wanted.items())
            raise ValueError(
                f"The recipe {source} and the base checkpoint define z differently ({details}). Train the "
                f"base with `{flags}`, or edit the recipe's `recovery:` section to match the checkpoint "
                "(or leave its z settings out: they default to the checkpoint's)."
            )
        delta_z = config.delta_z if self.delta_z is None else self.delta_z
        return dataclasses.replace(
            self, delta_z=delta_z, **{name: getattr(config, name) for name in Z_FIELDS}
        )


# The recipe's z settings (as CCDPConfig's), and those each kind of z reads besides `failure_feature`.
Z_FIELDS_OF = {
    "final_state": ("failure_state_dims",),
    "action": (),
    "primitive": ("primitive_key", "num_primitives"),
}
Z_FIELDS = ("failure_feature", *(name for names in Z_FIELDS_OF.values() for name in names))


def env_arguments(env_class: type) -> dict[str, Any]:
    """The keyword arguments an env class's constructor takes, following `**kwargs` up to its base classes,
    each with its annotation (Any where it has none)."""
    arguments: dict[str, Any] = {}
    for klass in env_class.__mro__:
        if "__init__" not in vars(klass):
            continue
        hints = typing.get_type_hints(klass.__init__)
        parameters = inspect.signature(klass.__init__).parameters.values()
        for p in parameters:
            if p.name != "self" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
                arguments.setdefault(p.name, hints.get(p.name, Any))
        if not any(p.kind is p.VAR_KEYWORD for p in parameters):
            break
    return arguments


def _build(cls: type, values: dict[str, Any], section: str, at: str):
    """Instantiate a recipe dataclass from its section, naming unknown, missing, mistyped and non-finite
    fields."""
    known = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ValueError(
            f"{at}unknown field(s) in `{section}:`: {', '.join(unknown)}; known: {', '.join(known)}"
        )
    required = [
        n
        for n, f in known.items()
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    missing = [n for n in required if n not in values]
    if missing:
        raise ValueError(f"{at}`{section}:` is missing required field(s): {', '.join(missing)}")
    hints = typing.get_type_hints(cls)
    for name, value in values.items():
        if not _has_type(value, hints[name]):
            raise ValueError(
                f"{at}{section}.{name} must be {_type_name(hints[name])}, got {value!r} "
                f"({type(value).__name__}); write it without quotes or decimals where a number is meant"
            )
        if (where := _non_finite(value, f"{section}.{name}")) is not None:
            raise ValueError(f"{at}{where} must be a finite number, not NaN or infinite")
    return cls(**values)


def _has_type(value: Any, hint: Any) -> bool:
    """Whether a YAML value fits a recipe field's annotation (bools are not numbers, ints are floats)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_has_type(value, arg) for arg in args)
    if hint is type(None):
        return value is None
    if hint is Any:
        return True
    if isinstance(value, bool):
        return hint is bool
    if hint is float:
        return isinstance(value, int | float)
    if origin in (list, tuple):  # YAML has lists only; a tuple argument takes one
        return isinstance(value, list) and all(_has_type(v, args[0]) for v in value)
    if origin is dict:
        return isinstance(value, dict)
    return isinstance(value, hint)


def _non_finite(value: Any, name: str) -> str | None:
    """The dotted name of the first NaN or infinite float in `value` (YAML's .nan, .inf), or None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else name
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    return next((where for key, item in items if (where := _non_finite(item, f"{name}.{key}"))), None)


def _type_name(hint: Any) -> str:
    return str(hint).replace("typing.", "") if typing.get_origin(hint) else hint.__name__
