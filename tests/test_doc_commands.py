"""The commands of README "Train on a local dataset", docs/synthesis.md, docs/troubleshooting.md and
configs/README.md run as written after the steps before them, and the messages troubleshooting.md quotes are
ones the code prints.

Every command is parsed by its own CLI's parser (draccus, as lerobot-train, lerobot-eval and this package's
commands parse it); the short ones run: the README's dataset command (twice: a rerun is refused in one line)
and, slow, the whole of docs/synthesis.md after the README's first two commands and configs/README.md's main
job, with small sizes."""

import ast
import importlib
import importlib.util
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import draccus
import pytest
import yaml
from lerobot.configs import parser
from lerobot.configs.eval import EvalPipelineConfig
from lerobot.configs.train import TrainPipelineConfig
from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata

from lerobot_ccdp.benchmark.episodes import Episodes
from lerobot_ccdp.datasets.configs import RecordConfig, SynthesizeConfig, parse_cli
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.recovery.synthesize import RECIPE_COPY

from fixtures.doc_commands import SMALL, commands, run_command, sized

REPO = Path(__file__).resolve().parent.parent
README_SECTION = (
    (REPO / "README.md").read_text().split("## Train on a local dataset\n", 1)[1].split("\n## ", 1)[0]
)
SYNTHESIS = (REPO / "docs" / "synthesis.md").read_text()
TROUBLESHOOTING = (REPO / "docs" / "troubleshooting.md").read_text()
CONFIGS_README = (REPO / "configs" / "README.md").read_text()
DOCS = {
    "README.md#train-on-a-local-dataset": README_SECTION,
    "docs/synthesis.md": SYNTHESIS,
    "configs/README.md": CONFIGS_README,
}
# Where the messages a user meets come from: this plugin, and the libraries whose messages the docs quote.
MESSAGE_SOURCES = ("lerobot_ccdp", "draccus", "torchcodec")


def parse_lerobot(config_class: type[TrainPipelineConfig | EvalPipelineConfig], args: list[str]) -> None:
    """A LeRobot script's parsing of `args` without running it, as `parser.wrap` does: a `--config_path` file
    through the class's `from_pretrained` where it has one (lerobot-train), else draccus reads it; and the
    `--policy.*` overrides of a `--policy.path` checkpoint over CCDPConfig (LeRobot applies them on load, so
    the checkpoint need not exist yet)."""
    config_path = parser.parse_arg("config_path", args)
    cli_args = parser.filter_path_args(config_class.__get_path_fields__(), args)
    if hasattr(config_class, "from_pretrained") and config_path:
        config_class.from_pretrained(config_path, cli_args=parser.filter_arg("config_path", cli_args))
    else:
        draccus.parse(config_class, args=cli_args)
    if parser.get_path_arg("policy", args):
        overrides = [f"--{a[len('--policy.') :]}" for a in args if a.startswith("--policy.")]
        draccus.parse(CCDPConfig, args=[a for a in overrides if not a.startswith("--path=")])


@pytest.mark.parametrize("doc", list(DOCS))
def test_every_command_parses_as_written(doc, monkeypatch):
    monkeypatch.chdir(REPO)  # a clone's root, where the docs' --config_path files are
    # EvalPipelineConfig reads --policy.path from sys.argv itself and would load the checkpoint
    monkeypatch.setattr(sys, "argv", ["pytest"])
    found = commands(DOCS[doc])
    assert found
    for argv in found:
        if argv[:2] == ["accelerate", "launch"]:  # `... $(which lerobot-train) <flags>`
            argv = ["lerobot-train", *argv[argv.index("$(which") + 2 :]]
        if argv[0] == "lerobot-train":
            parse_lerobot(TrainPipelineConfig, argv[1:])
        elif argv[0] == "lerobot-eval":
            parse_lerobot(EvalPipelineConfig, argv[1:])
        elif argv[0] == "lerobot-ccdp-record":
            parse_cli(RecordConfig, argv[1:])
        elif argv[0] == "lerobot-ccdp-synthesize":
            parse_cli(SynthesizeConfig, argv[1:])
        elif argv[:3] == ["python", "-m", "lerobot_ccdp.benchmark.reaching2d"]:
            assert argv[3:] == ["--root", "data/reaching2d"]  # run below
        else:
            raise AssertionError(f"{doc} runs a command this test does not parse: {argv}")


def test_the_readme_dataset_command_runs_and_a_rerun_is_refused_in_one_line(tmp_path, monkeypatch):
    (record,) = [argv for argv in commands(README_SECTION) if argv[0] == "python"]
    module, flags = record[2], record[3:]
    monkeypatch.chdir(tmp_path)
    importlib.import_module(module).main(flags)
    assert LeRobotDatasetMetadata("local/reaching2d", root="data/reaching2d").total_episodes == 60
    again = subprocess.run([sys.executable, *record[1:]], capture_output=True, text=True, check=False)
    assert again.returncode == 2 and "Traceback" not in again.stderr
    assert (
        again.stderr.strip()
        .splitlines()[-1]
        .endswith("data/reaching2d already exists; pass --overwrite to replace it, or choose another root")
    )


def source_messages() -> list[str]:
    """Every string literal and f-string of the message sources, with each formatted value (`{...}`, `%s`)
    as a NUL: a quoted message must match the literal text between them."""
    messages = []
    for package in MESSAGE_SOURCES:
        (folder,) = importlib.util.find_spec(package).submodule_search_locations
        for file in Path(folder).rglob("*.py"):
            for node in ast.walk(ast.parse(file.read_text())):
                if isinstance(node, ast.Constant) and isinstance(node.value, str):
                    messages.append(re.sub(r"%[-\d.]*[sdrf]", "\0", node.value))
                elif isinstance(node, ast.JoinedStr):
                    parts = (v.value if isinstance(v, ast.Constant) else "\0" for v in node.values)
                    messages.append("".join(parts))
    return messages


def test_troubleshooting_quotes_only_messages_the_code_prints():
    """A quoted message is a bold code span; `<...>` in it stands where the message formats a value, and the
    text around it must be a message's own text."""
    quotes = re.findall(r"\*\*`([^`]+)`\*\*", TROUBLESHOOTING)
    assert len(quotes) >= 10, quotes
    messages = source_messages()
    for quote in quotes:
        text = "\0".join(re.split(r"<[^>]*>", quote))
        assert any(text in m for m in messages), f"no message in {MESSAGE_SOURCES} prints {quote!r}"


@pytest.mark.slow  # two short lerobot-train runs and two syntheses, in-process (about 40 s)
def test_synthesis_doc_runs_as_written_after_the_readmes_first_commands(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a clone's root: its recipes, and the docs' data/ and outputs/
    (tmp_path / "datasets_recipes").symlink_to(REPO / "datasets_recipes")
    record, train_base, *_ = commands(README_SECTION)
    importlib.import_module(record[2]).main(record[3:])
    run_command(sized(train_base), monkeypatch)
    doc = commands(SYNTHESIS)
    assert len(doc) == 4
    for argv in doc:
        run_command(sized(argv), monkeypatch)
    for out in ("reaching2d_recovery", "reaching2d_goals_recovery"):
        written = yaml.safe_load((tmp_path / "data" / out / RECIPE_COPY).read_text())
        # the state data's default head: the README's path trains the set denoiser the benchmark measured
        assert written["recovery_head"] == "set_denoiser"
    assert (tmp_path / "outputs" / "reaching2d" / "ccdp" / "checkpoints" / "last").exists()


@pytest.mark.slow  # the door's main job by hand, in-process: record, two trainings, a synthesis, an eval
def test_configs_readme_main_job_runs_as_written(tmp_path, monkeypatch):
    """configs/README.md's commands in a clone's root (its configs/ and datasets_recipes/), only the sizes
    shrunk: each command of the main job finds what the one before it wrote and the eval writes the ccdp
    mode's metrics; then the second block's overrides replace the main job's datasets."""
    monkeypatch.chdir(tmp_path)
    for folder in ("configs", "datasets_recipes"):
        shutil.copytree(REPO / folder, tmp_path / folder)
    job = commands(CONFIGS_README.split("\n## ", 1)[0])
    expected = [
        "lerobot-ccdp-record",
        "lerobot-train",
        "lerobot-ccdp-synthesize",
        "lerobot-train",
        "lerobot-eval",
    ]
    assert [argv[0] for argv in job] == expected
    record, train_base, synthesize, train_recovery, evaluate = job
    outputs = tmp_path / "outputs" / "door_opening"
    weights = "checkpoints/last/pretrained_model/model.safetensors"

    run_command(sized(record), monkeypatch)
    n_demos = int(SMALL["lerobot-ccdp-record"]["--record.n_episodes"])
    assert LeRobotDatasetMetadata("local/door_opening", root="data/door_opening").total_episodes == n_demos
    run_command(sized(train_base), monkeypatch)
    assert (outputs / "train_base" / weights).is_file()
    run_command(sized(synthesize), monkeypatch)
    recovery = tmp_path / "data" / "door_opening_recovery"
    assert (recovery / RECIPE_COPY).is_file()
    run_command(sized(train_recovery), monkeypatch)
    assert (outputs / "train_recovery" / weights).is_file()
    run_command(sized(evaluate), monkeypatch)
    ccdp = outputs / "eval" / "ccdp"
    episodes = Episodes.from_eval_info(ccdp / "eval_info.json")  # with the ccdp metrics, or it raises
    assert len(episodes.success) == int(SMALL["lerobot-eval"]["--eval.n_episodes"])
    assert list((ccdp / "videos").rglob("*.mp4"))  # eval.json renders, as the doc says

    # The second block redoes the datasets with overrides, over the main job's own.
    record_again, synthesize_again = commands(CONFIGS_README.split("\n## ", 1)[1])
    run_command(sized(record_again), monkeypatch)
    run_command(sized(synthesize_again), monkeypatch)
    assert yaml.safe_load((recovery / RECIPE_COPY).read_text())["recovery"]["sigma"] == 0.05


def test_make_train_local_runs_the_readme_commands():
    """`make train-local` types the section's three commands: the same flags and settings, its own folders."""
    dry = subprocess.run(["make", "-n", "train-local"], cwd=REPO, capture_output=True, text=True, check=True)
    parts = dry.stdout.replace("\\\n", " ").split("&&")
    made = [shlex.split(part) for part in parts if re.search(r"bin/lerobot-", part)]
    section = README_SECTION.split("\n### ", 1)[0]
    typed = [argv for argv in commands(section) if argv[0].startswith("lerobot-")]
    assert [Path(argv[0]).name for argv in made] == [argv[0] for argv in typed]
    for make_argv, readme_argv in zip(made, typed, strict=True):
        assert _settings(make_argv) == _settings(readme_argv)


def _settings(argv: list[str]) -> dict[str, str | None]:
    """A command's flags with their values, those naming a place (roots, paths, repo ids) by name only."""
    flags = dict(arg.split("=", 1) for arg in argv if arg.startswith("--"))
    places = ("root", "path", "output_dir", "repo_id")
    return {k: None if k.endswith(places) else v for k, v in flags.items()}
