"""The README's commands run as written in a fresh shell: headless rendering without MUJOCO_GL, a robot
snippet that executes, and shell blocks that name only make targets, modules, console scripts and flags
that exist."""

import importlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from lerobot_ccdp.compat.headless import choose_headless_gl
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

from fixtures.policy_factory import untrained_checkpoint
from fixtures.reaching import BIN

REPO = Path(__file__).resolve().parent.parent
README = (REPO / "README.md").read_text()
CHECKPOINT_PLACEHOLDER = "<recovery run>/checkpoints/last/pretrained_model"

RENDER = """
import json, os
import lerobot_ccdp, gymnasium as gym
env = gym.make("lerobot_ccdp/DoorOpening-lite-v0", render_mode="rgb_array")
env.reset(seed=0)
frame = env.render()
env.close()
print(json.dumps({"shape": list(frame.shape), "gl": os.environ.get("MUJOCO_GL")}))
"""


def _blocks(language: str, text: str = README) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)


def _shell_lines() -> list[str]:
    """Every command line of the README's bash blocks, backslash continuations joined."""
    joined = (block.replace("\\\n", " ") for block in _blocks("bash"))
    return [line for block in joined for line in block.splitlines() if line.strip()]


def _command(line: str) -> str:
    return line.split(" #", 1)[0]


def test_importing_the_package_renders_without_a_display_or_mujoco_gl():
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run(
        [sys.executable, "-c", RENDER], capture_output=True, text=True, env=env, check=False
    )
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert len(report["shape"]) == 3 and report["shape"][2] == 3
    assert report["gl"] == "egl"


@pytest.fixture
def bare_linux(monkeypatch):
    """A Linux machine with no display and no MUJOCO_GL, as in a fresh SSH shell."""
    for name in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(sys, "platform", "linux")


def test_no_display_chooses_egl(bare_linux):
    choose_headless_gl()
    assert os.environ["MUJOCO_GL"] == "egl"


@pytest.mark.parametrize("value", ["osmesa", "glfw", ""])
def test_the_users_mujoco_gl_is_kept(bare_linux, monkeypatch, value):
    monkeypatch.setenv("MUJOCO_GL", value)
    choose_headless_gl()
    assert os.environ["MUJOCO_GL"] == value


@pytest.mark.parametrize("display", ["DISPLAY", "WAYLAND_DISPLAY"])
def test_a_display_keeps_mujocos_default(bare_linux, monkeypatch, display):
    monkeypatch.setenv(display, ":0")
    choose_headless_gl()
    assert "MUJOCO_GL" not in os.environ


def test_other_systems_keep_mujocos_default(bare_linux, monkeypatch):
    monkeypatch.setattr(sys, "platform", "darwin")  # macOS renders with CGL, no display variable needed
    choose_headless_gl()
    assert "MUJOCO_GL" not in os.environ


def _robot_snippet() -> str:
    section = README.split("## Use it on a robot", 1)[1].split("\n## ", 1)[0]
    (snippet,) = _blocks("python", section)
    assert CHECKPOINT_PLACEHOLDER in snippet
    return snippet


@pytest.mark.parametrize("state_shape", [(1, 2), (2,)], ids=["batched", "unbatched"])
def test_the_robot_snippet_runs_as_written(reaching_root, tmp_path, monkeypatch, state_shape):
    checkpoint = untrained_checkpoint(reaching_root, tmp_path / "ckpt")
    counts = []  # failures remembered right after the snippet's report_failure(), before its reset()
    report_failure = CCDPPolicy.report_failure

    def counted_report_failure(policy: CCDPPolicy, *args, **kwargs) -> None:
        report_failure(policy, *args, **kwargs)
        counts.append(policy.failure_count().tolist())

    monkeypatch.setattr(CCDPPolicy, "report_failure", counted_report_failure)
    # What the README says `observation` holds, for the 2-D dataset: its only input, observation.state.
    observation = {"observation.state": torch.rand(state_shape, dtype=torch.float32)}
    namespace = {"observation": observation}
    exec(_robot_snippet().replace(CHECKPOINT_PLACEHOLDER, str(checkpoint)), namespace)

    action = namespace["action"]
    assert action.shape == (1, 2) and action.device.type == "cpu"  # as the snippet's comment says
    assert counts == [[1]], "report_failure() in the snippet did not reach the policy"
    assert namespace["policy"].failure_count().numel() == 0  # and reset() forgot it


def test_make_targets_in_the_readme_exist():
    makefile = (REPO / "Makefile").read_text()
    targets = set(re.findall(r"^([\w.-]+)\s*:(?!=)", makefile, flags=re.MULTILINE))
    make = re.compile(r"(?:^|&&|;)\s*make\s+([\w-]+)")
    named = {t for line in _shell_lines() for t in make.findall(_command(line))}
    assert named and named <= targets, f"README names make targets the Makefile lacks: {named - targets}"


def test_python_modules_in_the_readme_import():
    pattern = re.compile(r"python[\d.]*\s+-m\s+(lerobot_ccdp[\w.]*)")
    modules = {m for line in _shell_lines() for m in pattern.findall(line)}
    assert modules
    for module in sorted(modules):
        importlib.import_module(module)


def test_console_scripts_in_the_readme_are_installed():
    scripts = {s for line in _shell_lines() for s in re.findall(r"\b(lerobot-[\w-]+)", line)}
    assert "lerobot-eval" in scripts
    missing = sorted(s for s in scripts if not (BIN / s).is_file())
    assert not missing, f"README names console scripts that {BIN} lacks: {missing}"


def test_the_install_section_activates_the_venv_that_bare_commands_need():
    bare = [line for line in _shell_lines() if re.match(r"\s*(lerobot-|python -m )", line)]
    install = README.split("## Install", 1)[1].split("\n## ", 1)[0]
    assert bare and "source .venv/bin/activate" in _blocks("bash", install)[0]


def test_every_lerobot_eval_in_the_readme_chooses_its_seeds():
    """Without --seed (or a config holding one) lerobot-eval runs the development seeds from 1000."""
    evals = [line for line in _shell_lines() if re.match(r"\s*lerobot-eval\b", line)]
    assert evals and all(re.search(r"--(seed|config_path)=", line) for line in evals), evals


def test_pipeline_flags_in_the_readme_are_in_its_help():
    prose = re.sub(r"```.*?```", "", README, flags=re.S)  # inline commands, outside the fenced blocks
    commands = _shell_lines() + [span.replace("\n", " ") for span in re.findall(r"`([^`]+)`", prose)]
    given = {
        f
        for line in commands
        for part in line.split("-m lerobot_ccdp.benchmark.pipeline")[1:]
        for f in re.findall(r"(?<![\w-])(--[a-z][\w-]*)", part)
    }
    assert given
    usage = subprocess.run(
        [sys.executable, "-m", "lerobot_ccdp.benchmark.pipeline", "--help"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    known = set(re.findall(r"--[a-z][\w-]*", usage))
    assert given <= known, f"README gives the pipeline flags its --help lacks: {given - known}"


def test_quickstart_writes_into_a_folder_per_task():
    result = subprocess.run(
        ["make", "-n", "quickstart", "TASK=X"], cwd=REPO, capture_output=True, text=True, check=True
    )
    assert re.search(r"--out outputs/quickstart/X(\s|$)", result.stdout, flags=re.MULTILINE), result.stdout
