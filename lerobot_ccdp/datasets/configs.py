"""Command-line configs of `lerobot-ccdp-record` and `lerobot-ccdp-synthesize`, parsed with draccus as
LeRobot's.

`--config_path=datasets_recipes/<task>.yaml` reads the command's own section of a recipe file (`record:` or
`recovery:`; the other one belongs to the other command) and dotted flags override any field
(`--record.n_episodes=2`, `--recovery.sigma=0.05`). Without `--config_path` every required field comes from
flags. `--help` lists every field with its default.
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
import typing
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import draccus
import yaml
from draccus.parsers.decoding import get_decoding_fn
from draccus.utils import DecodingError, DraccusException
from huggingface_hub.utils import validate_repo_id
from lerobot.configs import parser

from lerobot_ccdp.datasets.recipe_file import RecordRecipe, RecoveryRecipe, read_recipe_section

T = TypeVar("T", bound="RecipeCommandConfig")


@dataclass
class LocalDatasetConfig:
    """A LeRobot dataset on this machine (recorded or written here, never pushed)."""

    repo_id: str  # required: its repo id, e.g. local/door_opening
    root: Path  # required: its folder


@dataclass
class OutputDatasetConfig:
    """A LeRobot dataset this command writes on this machine."""

    root: Path  # required: its folder
    repo_id: str | None = None  # its repo id; null: local/<the root's folder name>

    def __post_init__(self):
        if self.repo_id is None:
            self.repo_id = f"local/{Path(self.root).name}"


@dataclass
class CheckpointConfig:
    """The base checkpoint synthesis samples from."""

    # required: a ccdp base checkpoint, the pretrained_model folder lerobot-train writes
    # (<run>/checkpoints/last/pretrained_model)
    path: Path
    # where the policy runs, e.g. cpu or cuda; null: the checkpoint's, or cpu if absent
    device: str | None = None
    # the recovery head whose rows to write (pairs for unet, base samples for set_denoiser), for another head
    # of the same base (lerobot-train's --policy.recovery_head at the recovery stage); null: the checkpoint's
    recovery_head: str | None = None


@dataclass
class RecipeCommandConfig:
    """A command that reads one section of a recipe file (`section`) into its field of that name."""

    section: ClassVar[str]
    command: ClassVar[str]


@dataclass
class RecordConfig(RecipeCommandConfig):
    """lerobot-ccdp-record: record scripted-expert demonstrations of a CCDP task as a local LeRobot dataset.

    --config_path=<recipe yaml> reads the file's `record:` section; --record.<field>=... flags override it."""

    record: RecordRecipe  # what to record: the `record:` section of the recipe file
    dataset: LocalDatasetConfig  # where to write the demonstrations
    # replace dataset.root once the new dataset is complete, if it holds one lerobot_ccdp wrote at that path
    overwrite: bool = False

    section: ClassVar[str] = "record"
    command: ClassVar[str] = "lerobot-ccdp-record"


@dataclass
class SynthesizeConfig(RecipeCommandConfig):
    """lerobot-ccdp-synthesize: turn demonstrations and a base checkpoint into a recovery dataset (eq. 5-7).

    Without --config_path every recovery field has its default and z is the base checkpoint's; a recipe file
    (--config_path=<recipe yaml>, its `recovery:` section) or --recovery.<field>=... flags change them."""

    dataset: LocalDatasetConfig  # the demonstrations the base was trained on
    policy: CheckpointConfig  # the base checkpoint, trained on `dataset`
    output: OutputDatasetConfig  # where to write the recovery dataset
    # how to synthesise: the `recovery:` section of the recipe file; z defaults to the checkpoint's
    recovery: RecoveryRecipe = field(default_factory=RecoveryRecipe)
    # replace output.root once the new dataset is complete, if it holds one lerobot_ccdp wrote at that path
    overwrite: bool = False

    section: ClassVar[str] = "recovery"
    command: ClassVar[str] = "lerobot-ccdp-synthesize"


@draccus.decode.register(RecipeCommandConfig, include_subclasses=True)
def _decode(config_class: type[RecipeCommandConfig], raw_value: dict[str, Any], path: Sequence[str]):
    """The recipe section goes through its recipe's own checks (`from_dict`: unknown fields, strict types,
    ranges, the same messages as for a recipe file), every other field as draccus decodes it."""
    hints = typing.get_type_hints(config_class)
    values = {}
    for name, value in raw_value.items():
        if name != config_class.section:
            values[name] = get_decoding_fn(hints[name])(value, (*path, name))
        elif isinstance(value, dict):
            values[name] = hints[name].from_dict(value)
        else:
            raise DecodingError((*path, name), f"must be a mapping of fields, got {value!r}")
    return config_class(**values)


def parse_cli(config_class: type[T], args: Sequence[str] | None = None) -> T:
    """Parse `args` (default: sys.argv[1:]) into `config_class`; a wrong flag or value exits naming it.

    As LeRobot's `parser.wrap`, but `--config_path` names a recipe file of which only the command's own
    section (`config_class.section`) is read, so one file serves both commands."""
    args = sys.argv[1:] if args is None else list(args)
    config_path, args = parser.parse_arg("config_path", args), parser.filter_arg("config_path", args)
    section = config_class.section
    try:
        # draccus would read the whole file, both sections, as this command's config
        if "--config_path" in args:
            raise ValueError("write the recipe as --config_path=<recipe yaml>, with '='")
        file_values = {section: read_recipe_section(config_path, section)} if config_path else {}
        missing = [f"--{name}" for name in _required_fields(config_class) if not _given(name, args)]
        # the section's own check names what the file lacks, after any unknown (misspelt) field
        if config_path:
            missing = [flag for flag in missing if not flag.startswith(f"--{section}.")]
        if missing and not {"-h", "--help"} & set(args):
            hint = (
                f" (or name a recipe file holding the {section}.* ones with --config_path=<recipe yaml>)"
                if any(flag.startswith(f"--{section}.") for flag in missing)
                else ""
            )
            raise ValueError(f"missing required flag(s): {', '.join(missing)}{hint}")
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "config.yaml"
            path.write_text(yaml.safe_dump(file_values))
            with draccus.config_type("yaml"):  # the type draccus parses flag values with, as for the file
                config = draccus.parse(config_class, path, args=args, prog=config_class.command)
        _check_repo_ids(config)
        return config
    except (DraccusException, ValueError, FileNotFoundError) as error:
        raise SystemExit(f"{config_class.command}: error: {error}") from None


def _check_repo_ids(config: RecipeCommandConfig) -> None:
    """Every dataset's repo id as the Hub and LeRobot's loaders take it: an empty or spaced one was recorded,
    then refused by the training that read it."""
    for f in dataclasses.fields(config):
        dataset = getattr(config, f.name)
        if isinstance(dataset, LocalDatasetConfig | OutputDatasetConfig):
            try:
                validate_repo_id(dataset.repo_id)
            except ValueError as error:
                raise ValueError(
                    f"--{f.name}.repo_id={dataset.repo_id!r} is not a repo id: {str(error).rstrip('.')}. "
                    "Write namespace/name, e.g. local/door_opening"
                ) from None


def _required_fields(config_class: type, prefix: str = "") -> list[str]:
    """Dotted names of the fields that have no default, nested configs included."""
    hints = typing.get_type_hints(config_class)
    names = []
    for f in dataclasses.fields(config_class):
        if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING:
            continue
        name, hint = prefix + f.name, hints[f.name]
        names += _required_fields(hint, f"{name}.") if dataclasses.is_dataclass(hint) else [name]
    return names


def _given(name: str, args: Sequence[str]) -> bool:
    """Whether a flag sets field `name`: `--a.b=...`, or `--a=...` for the whole of `a`."""
    parts = name.split(".")
    flags = {"--" + ".".join(parts[: i + 1]) for i in range(len(parts))}
    return any(arg.split("=", 1)[0] in flags for arg in args)
