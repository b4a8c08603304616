"""The settings docs say what the configs hold: configs/README.md's table of what each settings folder sets is
the one `python -m lerobot_ccdp.benchmark.task_settings` writes from the files, and every default the README's
"Settings that matter" states is `CCDPConfig`'s or `RecoveryRecipe`'s (issue 114)."""

import json
import re
import shutil
from pathlib import Path

import pytest
import yaml

from lerobot_ccdp.benchmark.task_settings import BEGIN, END, defaults, main
from lerobot_ccdp.datasets.recipe_file import RecoveryRecipe
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

REPO = Path(__file__).resolve().parents[2]
CONFIGS, RECIPES = REPO / "configs", REPO / "datasets_recipes"
README = (REPO / "README.md").read_text()
# A row's settings, `--policy.<field>` (CCDPConfig) or `--recovery.<field>` (RecoveryRecipe), and its default
# cell written strictly: one backticked YAML value per setting, in the same order.
SETTING = re.compile(r"`--(policy|recovery)\.(\w+)`")
STRICT = re.compile(r"`[^`]+`(, `[^`]+`)*")
CODE = {"policy": defaults(CCDPConfig), "recovery": defaults(RecoveryRecipe)}


def wrong_defaults(readme: str) -> tuple[list[str], int]:
    """The README settings table's defaults that are not the code's (or not written strictly), and how many
    settings the table states a default for."""
    section = readme.split("## Settings that matter\n", 1)[1].split("\n## ", 1)[0]
    problems, stated = [], 0
    for row in (line for line in section.splitlines() if line.startswith("| `--")):
        cells = [cell.strip() for cell in row.strip().strip("|").split("|")]
        names, cell = SETTING.findall(cells[0]), cells[-1]
        if not names:
            continue
        values = re.findall(r"`([^`]+)`", cell)
        if not STRICT.fullmatch(cell) or len(values) != len(names):
            problems.append(f"{cells[0]}: write the default cell as one `value` per setting, got {cell!r}")
            continue
        for (kind, name), value in zip(names, values, strict=True):
            stated += 1
            code = CODE[kind].get(name, "no such field")
            if yaml.safe_load(value) != code:
                problems.append(f"--{kind}.{name}: the README says {value}, the code {code!r}")
    return problems, stated


def test_the_readme_states_the_codes_defaults():
    problems, stated = wrong_defaults(README)
    assert problems == []
    assert stated >= 19  # every row was read, not skipped


def test_a_default_the_readme_misstates_or_writes_loosely_is_found():
    wrong = README.replace("| `5`, `3` |", "| `1`, `3` |").replace(
        "| `0.1` |", "| 0.1 / 0.05 (methods.json) |"
    )
    assert wrong != README
    problems, _ = wrong_defaults(wrong)
    assert problems == [
        "--policy.w_z: the README says 1, the code 5.0",
        "`--policy.delta_z`: write the default cell as one `value` per setting, got "
        "'0.1 / 0.05 (methods.json)'",
    ]


def test_configs_readme_holds_the_table_the_files_give(capsys):
    main(
        [
            "--configs",
            str(CONFIGS),
            "--recipes",
            str(RECIPES),
            "--readme",
            str(CONFIGS / "README.md"),
            "--check",
        ]
    )
    assert "is current" in capsys.readouterr().out


def test_a_changed_config_makes_the_table_stale_until_it_is_written_again(tmp_path):
    configs = shutil.copytree(CONFIGS, tmp_path / "configs")
    readme = configs / "README.md"
    before = readme.read_text()
    base, head = (
        configs / "door_opening" / "train_base.json",
        configs / "door_opening" / "train_recovery.json",
    )
    config = json.loads(base.read_text())
    config["policy"]["w_z"] = 2.0
    base.write_text(json.dumps(config))
    config = json.loads(head.read_text())
    config["steps"] = 700
    head.write_text(json.dumps(config))
    args = ["--configs", str(configs), "--recipes", str(RECIPES), "--readme", str(readme)]
    with pytest.raises(SystemExit, match=r"not what .* hold: rerun .*task_settings --write"):
        main([*args, "--check"])

    main([*args, "--write"])
    main([*args, "--check"])
    after = readme.read_text()
    row = next(line for line in after.splitlines() if line.startswith("| `door_opening` |"))
    assert "`w_z` 2.0" in row and "| 700 x 128 |" in row
    assert after.split(BEGIN)[0] == before.split(BEGIN)[0]  # only the block changed
    assert after.split(END)[1] == before.split(END)[1]


def test_a_folder_the_pipeline_cannot_run_is_refused(tmp_path):
    configs = shutil.copytree(CONFIGS, tmp_path / "configs")
    shutil.copytree(configs / "door_opening", configs / "door_opening_v2")
    with pytest.raises(SystemExit, match="door_opening_v2 name no task"):
        main(["--configs", str(configs), "--recipes", str(RECIPES), "--readme", str(configs / "README.md")])
