"""`python -m lerobot_ccdp.benchmark.task_settings`: what each settings folder under configs/ sets beyond
`CCDPConfig`'s and `RecoveryRecipe`'s defaults, the table configs/README.md shows.

A task's folder should describe the task and its data (paths, the chunk, what z is, training sizes) and leave
every method setting at the defaults (issue 114's one configuration). `method_settings` finds each method
setting a folder still sets, wherever it hides: the base's policy fields beyond the task-describing ones, a
training file's own fields, methods.json and the recipe's synthesis fields. The table is written from the
files (`--write`), so the docs say what the configs hold, and `--check` fails when they no longer do.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Any

import yaml

from lerobot_ccdp.benchmark.pipeline import LABEL_FREE, OBS_VARIANTS, TaskFiles, task_slug
from lerobot_ccdp.benchmark.results import with_block
from lerobot_ccdp.datasets.recipe_file import Z_FIELDS, RecoveryRecipe
from lerobot_ccdp.envs import TASKS
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

# train_base.json's policy fields that describe the task and its data: the chunk (horizon, steps executed
# per plan), what z is (Z_FIELDS: the option label, or which state dims) and where a label-free demo's
# option ends.
TASK_POLICY_FIELDS = {"type", "push_to_hub", "horizon", "n_action_steps", "failure_segments", *Z_FIELDS}
# The training files' own fields: paths, seed, sizes and logging (the table shows each stage's steps and
# batch size).
TRAINING_FIELDS = {"dataset", "policy", "output_dir", "seed", "steps", "batch_size", "num_workers"}
TRAINING_FIELDS |= {"log_freq", "save_freq", "wandb"}
# The base's length, one rule for every task (issue 114): the fewest whole 800-step intervals that give at
# least 19 epochs over the demonstrated frames at the training file's batch size. It is the length the door,
# box, buttons and packing were benchmarked with (19-29 epochs at batch 64). The Bartender does not fit it
# yet: at its 1600 steps both of its folders lost 0.16-0.19 of success on the development seeds, and at 7200
# (86 epochs) both did best (docs/benchmarks.md, "The Bartenders at the one configuration"), listed as open
# in tests/benchmark/test_one_configuration.py.
BASE_EPOCHS, BASE_STEP_UNIT = 19, 800
BEGIN = (
    "<!-- settings:begin (written by python -m lerobot_ccdp.benchmark.task_settings --write; do not edit) -->"
)
END = "<!-- settings:end -->"


def method_settings(files: TaskFiles) -> dict[str, dict]:
    """Every method setting of a task's folder and recipe, by file (only the files that set one);
    methods.json's as `method.field`."""
    base = json.loads(files.train_base.read_text())
    found = {"train_base": {k: v for k, v in base["policy"].items() if k not in TASK_POLICY_FIELDS}}
    for name, path in (("train_base", files.train_base), ("train_recovery", files.train_recovery)):
        config = json.loads(path.read_text())
        found.setdefault(name, {}).update({k: v for k, v in config.items() if k not in TRAINING_FIELDS})
    methods = files.eval.with_name("methods.json")
    if methods.is_file():
        found["methods"] = {
            f"{method}.{k}": v
            for method, fields in json.loads(methods.read_text()).items()
            for k, v in fields.items()
        }
    recovery = yaml.safe_load(files.recipe.read_text())["recovery"] or {}
    found["recipe"] = {k: v for k, v in recovery.items() if k not in Z_FIELDS}
    return {name: fields for name, fields in found.items() if fields}


def base_steps(frames: int, batch_size: int) -> int:
    """The base's training steps for `frames` demonstrated frames at `batch_size`, by the rule above."""
    return BASE_STEP_UNIT * math.ceil(BASE_EPOCHS * frames / (batch_size * BASE_STEP_UNIT))


def defaults(config_class: type) -> dict[str, Any]:
    """A config dataclass's field defaults (default factories called)."""
    return {
        f.name: f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
        for f in dataclasses.fields(config_class)
        if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
    }


def settings_folders(configs: Path, recipes: Path) -> list[TaskFiles]:
    """Every settings folder under `configs`, in TASKS' order (state, label-free, camera), refusing one the
    pipeline cannot run."""
    found = []
    for task in TASKS:
        for obs_type, suffix in OBS_VARIANTS.items():
            for label_free in (False, True):
                if (configs / (task_slug(task) + suffix + (LABEL_FREE if label_free else ""))).is_dir():
                    found.append(
                        TaskFiles.locate(task, configs, recipes, Path("outputs"), obs_type, label_free)
                    )
    unknown = {p.name for p in configs.iterdir() if p.is_dir()} - {f.train_base.parent.name for f in found}
    if unknown:
        raise ValueError(
            f"{configs}: folder(s) {', '.join(sorted(unknown))} name no task of lerobot_ccdp.envs.TASKS: "
            "name them <task>[_pixels][_label_free] (docs/tasks.md) or move them out of the configs folder"
        )
    return found


def _value(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value)


def _listed(settings: dict[str, Any]) -> str:
    return ", ".join(f"`{k}` {_value(v)}" for k, v in settings.items())


def row(files: TaskFiles) -> str:
    """One folder's line: its chunk and z, then what departs from the defaults and how long each stage
    trains."""
    policy_defaults, recipe_defaults = defaults(CCDPConfig), defaults(RecoveryRecipe)
    base, head = (json.loads(p.read_text()) for p in (files.train_base, files.train_recovery))
    policy = {**policy_defaults, **base["policy"]}
    z = policy["failure_feature"]
    if z == "primitive":
        z += f", {policy['num_primitives']} options"
    elif z == "final_state":
        z += f" dims {_value(policy['failure_state_dims'])}, option ends: {policy['failure_segments']}"
    found = method_settings(files)
    method = {
        k: v
        for name in ("train_base", "train_recovery")
        for k, v in found.get(name, {}).items()
        if name == "train_recovery" or policy_defaults.get(k) != v
    }
    at_eval: dict[str, dict[str, Any]] = {}
    for key, value in found.get("methods", {}).items():
        name, field = key.split(".", 1)
        if policy_defaults.get(field) != value:
            at_eval.setdefault(name, {})[field] = value
    cells = [_listed(method)] if method else []
    cells += [f"{name} at evaluation: {_listed(fields)}" for name, fields in at_eval.items()]
    synthesis = {k: v for k, v in found.get("recipe", {}).items() if recipe_defaults.get(k) != v}
    return (
        f"| `{files.train_base.parent.name}` | {policy['horizon']} / {policy['n_action_steps']} | {z} | "
        f"{'; '.join(cells) or '-'} | {_listed(synthesis) or '-'} | {base['steps']} x {base['batch_size']} | "
        f"{head['steps']} x {head['batch_size']} |"
    )


def table(configs: Path, recipes: Path) -> str:
    """The markdown table of every settings folder under `configs`."""
    return "\n".join(
        [
            "| folder | chunk / executed | z | method settings beyond the defaults | synthesis beyond the "
            "defaults | base steps x batch | head steps x batch |",
            "|---|---|---|---|---|---|---|",
            *(row(files) for files in settings_folders(configs, recipes)),
        ]
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--configs", type=Path, default=Path("configs"), help="folder of <task>/*.json configs"
    )
    parser.add_argument(
        "--recipes", type=Path, default=Path("datasets_recipes"), help="folder of <task>.yaml recipes"
    )
    parser.add_argument(
        "--readme", type=Path, default=Path("configs/README.md"), help="the file holding the table's markers"
    )
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--write", action="store_true", help="write the table between --readme's markers")
    mode.add_argument("--check", action="store_true", help="fail unless --readme holds the current table")
    args = parser.parse_args(argv)
    try:
        body = table(args.configs, args.recipes)
        text = with_block(args.readme, body, BEGIN, END) if args.write or args.check else ""
    except (OSError, ValueError) as error:
        sys.exit(str(error))
    if args.write:
        args.readme.write_text(text)
        print(f"Wrote the settings table in {args.readme}")
    elif args.check:
        if text != args.readme.read_text():
            sys.exit(
                f"{args.readme}'s settings table is not what {args.configs} and {args.recipes} hold: rerun "
                "`python -m lerobot_ccdp.benchmark.task_settings --write` (make settings-table)"
            )
        print(f"{args.readme}'s settings table is current")
    else:
        print(body)


if __name__ == "__main__":
    main()
