"""lerobot-ccdp-record and lerobot-ccdp-synthesize parse as LeRobot's CLIs: draccus,
`--config_path=<recipe yaml>` (each command reads only its own section), dotted overrides checked like the
file, `--help` with every default."""

import dataclasses
import re
from pathlib import Path

import pytest
import yaml
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_ccdp.datasets import record
from lerobot_ccdp.datasets.configs import (
    CheckpointConfig,
    LocalDatasetConfig,
    OutputDatasetConfig,
    RecordConfig,
    SynthesizeConfig,
    parse_cli,
)
from lerobot_ccdp.datasets.recipe_file import RecordRecipe, RecoveryRecipe

from fixtures.reaching import run_cli

DOOR = Path(__file__).parents[2] / "datasets_recipes" / "door_opening.yaml"
DEMOS = ["--dataset.repo_id=local/door", "--dataset.root=data/door"]
SYNTHESIS = [
    *DEMOS,
    "--policy.path=runs/base",
    "--output.repo_id=local/door_recovery",
    "--output.root=data/rec",
]


def help_entries(text: str) -> dict[str, str]:
    """`--flag` -> its help text (after the type, whitespace collapsed) in draccus's --help output."""
    entries = {}
    for block in text.split("\n  --")[1:]:
        flag, _type, *help_text = block.split(maxsplit=2)
        entries[f"--{flag}"] = " ".join(" ".join(help_text).split())
    return entries


@pytest.mark.parametrize(
    "config_class, recipe_class", [(RecordConfig, RecordRecipe), (SynthesizeConfig, RecoveryRecipe)]
)
def test_help_lists_every_field_with_its_default(config_class, recipe_class, capsys):
    with pytest.raises(SystemExit) as exit_info:
        parse_cli(config_class, ["--help"])
    assert exit_info.value.code == 0
    entries = help_entries(capsys.readouterr().out)
    nested = {
        config_class.section: recipe_class,
        "dataset": LocalDatasetConfig,
        "output": OutputDatasetConfig,
        "policy": CheckpointConfig,
    }
    expected = {}
    for top in dataclasses.fields(config_class):
        children = dataclasses.fields(nested[top.name]) if top.name in nested else [top]
        prefix = f"{top.name}." if top.name in nested else ""
        for f in children:
            expected[f"--{prefix}{f.name}"] = f
    assert set(expected) <= set(entries), set(expected) - set(entries)
    for flag, f in expected.items():
        if f.default is not dataclasses.MISSING:
            assert f"(default: {f.default})" in entries[flag], (flag, entries[flag])
        elif f.default_factory is not dataclasses.MISSING:
            assert f"(default: {f.default_factory()})" in entries[flag], (flag, entries[flag])
        else:
            assert entries[flag].startswith("required:"), (flag, entries[flag])


@pytest.mark.slow  # a process start per command (about 20 s in all on the slower machine)
def test_the_installed_commands_answer_help():
    for command in ("lerobot-ccdp-record", "lerobot-ccdp-synthesize"):
        assert "--config_path" in run_cli(command, "--help").stdout


def test_a_dotted_override_changes_what_is_recorded(tmp_path):
    root = tmp_path / "door"
    flags = [f"--config_path={DOOR}", "--dataset.repo_id=local/door", f"--dataset.root={root}"]
    record.main([*flags, "--record.n_episodes=2"])
    assert LeRobotDataset("local/door", root=root).num_episodes == 2
    with pytest.raises(SystemExit, match="already exists; pass --overwrite=true to replace it"):
        record.main([*flags, "--record.n_episodes=1"])
    record.main([*flags, "--record.n_episodes=1", "--overwrite=true"])
    assert LeRobotDataset("local/door", root=root).num_episodes == 1


def test_overrides_merge_with_the_own_section_of_the_recipe_file():
    file = yaml.safe_load(DOOR.read_text())
    cfg = parse_cli(
        SynthesizeConfig,
        [
            f"--config_path={DOOR}",
            *SYNTHESIS,
            "--recovery.sigma=0.05",
            "--recovery.delta_z=0.2",
            "--policy.device=cpu",
        ],
    )
    assert cfg.recovery == RecoveryRecipe.from_dict({**file["recovery"], "sigma": 0.05, "delta_z": 0.2})
    assert cfg.policy == CheckpointConfig(path=Path("runs/base"), device="cpu")
    assert cfg.output == OutputDatasetConfig(Path("data/rec"), "local/door_recovery") and not cfg.overwrite
    cfg = parse_cli(RecordConfig, [f"--config_path={DOOR}", *DEMOS, "--overwrite=true"])
    assert cfg.record == RecordRecipe.from_dict(file["record"]) and cfg.overwrite


def test_each_command_reads_only_its_own_section(tmp_path):
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(
        yaml.safe_dump(
            {
                "record": {"task": "DoorOpening-lite-v0", "n_episodes": 3, "seed": 0},
                "recovery": {"no_such_field": 1},
            }
        )
    )
    assert parse_cli(RecordConfig, [f"--config_path={recipe}", *DEMOS]).record.n_episodes == 3
    with pytest.raises(SystemExit, match=r"unknown field\(s\) in `recovery:`: no_such_field"):
        parse_cli(SynthesizeConfig, [f"--config_path={recipe}", *SYNTHESIS])


def test_a_config_builds_from_flags_alone():
    cfg = parse_cli(
        RecordConfig,
        [
            "--record.task=ButtonSearch-lite-v0",
            "--record.n_episodes=5",
            "--record.seed=7",
            "--record.env_kwargs={obs_type: pixels_agent_pos}",
            *DEMOS,
        ],
    )
    assert cfg.record == RecordRecipe(
        task="ButtonSearch-lite-v0", n_episodes=5, seed=7, env_kwargs={"obs_type": "pixels_agent_pos"}
    )
    assert cfg.dataset == LocalDatasetConfig("local/door", Path("data/door"))
    cfg = parse_cli(SynthesizeConfig, ["--recovery.sigma=0.05", *SYNTHESIS])
    assert cfg.recovery == RecoveryRecipe(sigma=0.05) and cfg.policy.device is None


@pytest.mark.parametrize(
    "config_class, flag, message",
    [
        (RecordConfig, "--record.n_episodes=abc", "record.n_episodes must be int, got 'abc'"),
        (RecordConfig, "--record.n_episodes=true", "record.n_episodes must be int, got True"),
        (RecordConfig, "--record.n_episodes=0", "record.n_episodes must be a positive integer, got 0"),
        (RecordConfig, "--record.task=Door-v9", "known tasks: DoorOpening-v0"),
        (SynthesizeConfig, "--recovery.sigma=abc", "recovery.sigma must be float, got 'abc'"),
        (SynthesizeConfig, "--recovery.w_s=2", r"recovery.w_s must be in \(0, 1\]"),
        (SynthesizeConfig, "--overwrite=maybe", "`overwrite`: Couldn't parse 'maybe' into a bool"),
    ],
)
def test_a_bad_override_is_refused_naming_the_field(config_class, flag, message):
    flags = DEMOS if config_class is RecordConfig else SYNTHESIS
    with pytest.raises(SystemExit, match=f"^{config_class.command}: error: .*{message}"):
        parse_cli(config_class, [f"--config_path={DOOR}", *flags, flag])


def test_an_unknown_field_is_refused_naming_it(capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_info:
        parse_cli(RecordConfig, [f"--config_path={DOOR}", *DEMOS, "--record.n_epsiodes=3"])
    assert exit_info.value.code == 2
    assert "unrecognized arguments: --record.n_epsiodes=3" in capsys.readouterr().err
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(yaml.safe_dump({"record": {"task": "DoorOpening-lite-v0", "n_epsiodes": 3, "seed": 0}}))
    with pytest.raises(SystemExit, match=r"unknown field\(s\) in `record:`: n_epsiodes"):
        parse_cli(RecordConfig, [f"--config_path={recipe}", *DEMOS])


def test_missing_required_fields_name_their_flags(tmp_path):
    with pytest.raises(SystemExit, match=r"missing required flag\(s\): --dataset.root$"):
        parse_cli(RecordConfig, [f"--config_path={DOOR}", "--dataset.repo_id=local/door"])
    with pytest.raises(
        SystemExit,
        match=re.escape(
            "missing required flag(s): --record.task, --record.n_episodes, --record.seed, --dataset.root "
            "(or name a recipe file holding the record.* ones with --config_path=<recipe yaml>)"
        ),
    ):
        parse_cli(RecordConfig, ["--dataset.repo_id=local/door"])
    with pytest.raises(SystemExit, match=r"missing required flag\(s\): --policy.path, --output.root$"):
        parse_cli(SynthesizeConfig, [f"--config_path={DOOR}", *DEMOS])
    # The recovery section needs no field: z is the checkpoint's, the rest has defaults.
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(yaml.safe_dump({"recovery": {"sigma": 0.1}}))
    assert parse_cli(SynthesizeConfig, [f"--config_path={recipe}", *SYNTHESIS]).recovery == RecoveryRecipe(
        sigma=0.1
    )


def test_a_missing_or_unfit_recipe_file_is_named(tmp_path):
    missing = tmp_path / "no_such_recipe.yaml"
    with pytest.raises(SystemExit, match=f"lerobot-ccdp-record: error: Recipe file not found: {missing}"):
        parse_cli(RecordConfig, [f"--config_path={missing}", *DEMOS])
    with pytest.raises(SystemExit, match="--config_path=<recipe yaml>, with '='"):
        parse_cli(RecordConfig, ["--config_path", str(DOOR), *DEMOS])
    # a `recovery:` section only: its demos come from another recorder
    reaching = DOOR.with_name("reaching2d.yaml")
    with pytest.raises(SystemExit, match=f"Recipe {reaching} has no top-level `record:` section"):
        parse_cli(RecordConfig, [f"--config_path={reaching}", *DEMOS])
