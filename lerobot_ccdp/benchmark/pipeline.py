"""`python -m lerobot_ccdp.benchmark.pipeline`: the CCDP main job end to end through the real CLIs, and the
paper's comparison.

Per task: record demos (lerobot-ccdp-record), train the base stage (lerobot-train), synthesise the recovery
dataset (lerobot-ccdp-synthesize), train the recovery stage (lerobot-train), evaluate every method on the same
seeds (lerobot-eval --policy.recovery_mode=...), run the no-repeat oracle on those seeds, and report the
metrics with 95% intervals (`lerobot_ccdp.benchmark.comparison`) as markdown, JSON and a bar chart.
`--methods ... ccdp_eps_z` adds the paper's own form, eq. (4) with the eps_z heads, synthesised and trained
from the same base in stages of its own beside the task's head (`HEAD_METHODS`, docs/benchmarks.md).

Settings live in files a user can run by hand: `configs/<task>/{train_base,train_recovery,eval}.json` and
`datasets_recipes/<task>.yaml`; `--obs-type pixels_agent_pos` runs the camera variant from
`configs/<task>_pixels/` and `datasets_recipes/<task>_pixels.yaml`, `--label-free` the variant without labels
(z where an option ends) from `configs/<task>_label_free/` and `datasets_recipes/<task>_label_free.yaml`. The
pipeline only moves every output under `--out/<task>/` (datasets, checkpoints, eval_info.json, logs). A stage
whose output exists is skipped, so an interrupted run resumes; `--fresh` starts over. The pipeline writes only
into a folder it created or adopted, marked as its own (`lerobot_ccdp.datasets.ownership`), and deletes
nothing else. `--publish` copies the report (all tasks) into the docs; `--publish-each` copies each task's own
report as soon as the task is done, so that a round of many hours keeps its finished tasks across a stop. Both
replace only files the pipeline published (`lerobot_ccdp.benchmark.published`), and every input is checked
before any stage runs.
"""

from __future__ import annotations

import argparse
import functools
import itertools
import json
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch
from lerobot.configs.types import FeatureType
from lerobot.envs.utils import env_to_policy_features

from lerobot_ccdp.benchmark.comparison import (
    EPS_Z,
    METHOD_LABELS,
    Episodes,
    MethodMetrics,
    Results,
    bar_chart,
    lost_table,
    markdown_table,
)
from lerobot_ccdp.benchmark.published import REPORT_NOTE, check_report_targets
from lerobot_ccdp.benchmark.results import command_line, save_run
from lerobot_ccdp.benchmark.run_lock import PipelineRunning, die_with_parent, exclusive
from lerobot_ccdp.benchmark.stage_stamps import StampBook, stamp
from lerobot_ccdp.benchmark.targets import target_checks
from lerobot_ccdp.compat.env_fit import NUMPY_SEEDS
from lerobot_ccdp.datasets.ownership import MARKER, NotOwned, check_output_folder, claim_output_folder
from lerobot_ccdp.datasets.recipe_file import RecordRecipe, RecoveryRecipe
from lerobot_ccdp.envs import TASKS, CCDPEnvConfig
from lerobot_ccdp.envs.scripted import NoRepeatOracle, run_episode
from lerobot_ccdp.envs.tasks import is_lite
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.heads import head_class, head_of
from lerobot_ccdp.policy.heads.registry import HEADS

METHODS = ("dp", "dp_star", "dp_star_matched", "ccdp", EPS_Z)
# `--methods` unless told: the comparison with the task's own head. EPS_Z, the paper's own form beside it,
# trains a head of its own (hours on a Panda task), so it runs only when asked.
DEFAULT_METHODS = METHODS[:4]
# The recovery_mode each method evaluates with. "dp_star_matched" is the compute-matched baseline: DP* with
# its own settings (how it reads z) but the candidates that fit in CCDP's measured per-plan cost
# (MATCHED_DP_STAR unless methods.json names its own), so that CCDP - matched DP* shows what composition buys
# over rejection at equal compute.
RECOVERY_MODE = {
    "dp": "dp",
    "dp_star": "dp_star",
    "dp_star_matched": "dp_star",
    "ccdp": "ccdp",
    EPS_Z: "ccdp",
}


@dataclass(frozen=True)
class HeadStages:
    """A recovery head trained from the task's base: which (None: the task's own, train_base.json's
    `recovery_head`; a name: that head, `--policy.recovery_head` at synthesis and training) and the suffix of
    its stages and folders (`synthesize<suffix>`, `train_recovery<suffix>`, `recovery_data<suffix>/`,
    `recovery<suffix>/`)."""

    head: str | None = None
    suffix: str = ""


# The methods that sample a recovery head, and the head each samples: CCDP the task's own, EPS_Z eq. (4)'s
# eps_z heads (`unet`), synthesised with the task's recipe and trained with its train_recovery.json from the
# same base. The other methods sample the base alone and are evaluated on the base's checkpoint while the
# heads are synthesised and trained beside them.
HEAD_METHODS = {"ccdp": HeadStages(), EPS_Z: HeadStages("unet", "_eps_z")}
MATCHED_DP_STAR = {"dp_star_candidates": 2, "dp_star_rounds": 1}
# Every method's evaluation runs with `--env.render_mode=null`, so its wall time measures the method alone (on
# the Panda each rendered frame costs about 40 ms, and LeRobot renders 10 envs at every step of the first
# batch). The pair `lerobot_ccdp.benchmark.watch` shows side by side, DP and CCDP, is rendered in a stage of
# its own: the first VIDEO_EPISODES episodes again, on the same seeds and noise streams, under
# `<task>/videos/<method>/`.
VIDEO_METHODS = ("dp", "ccdp")
VIDEO_EPISODES = 10
# Every method is evaluated on common random numbers: each episode's plans draw from the same per-row noise
# streams (`lerobot_ccdp.policy.samplers.row_generators`), so DP, DP* and CCDP act alike until an episode's
# first failure and the paired differences measure recovery, not the luck of the plans before it.
COMMON_NOISE = "--policy.row_noise_streams=true"
# Named groups of --tasks: the benchmark's five tasks (contact physics on the Panda), and their geometric
# versions.
TASK_GROUPS = {
    "all": [t for t in TASKS if not is_lite(t)],
    "lite": [t for t in TASKS if is_lite(t)],
}
# Observation type -> suffix of the settings folder and recipe that hold its configs.
OBS_VARIANTS = {"state": "", "pixels_agent_pos": "_pixels"}
LABEL_FREE = "_label_free"  # the settings folders of the variant without option labels
BIN = Path(sys.executable).parent
CHECKPOINT = Path("checkpoints/last/pretrained_model")
# Per-episode outcomes of every method, with the command and commit (`lerobot_ccdp.benchmark.results`).
RUN_FILE = "episodes.json"
# What write_report writes into --out and into each task's folder in it.
REPORT_FILES = ("report.md", "summary.json", RUN_FILE, "comparison.png")
# lerobot-train's periodic log line: seconds per step spent updating and waiting for data.
STEP_TIMES = re.compile(r"updt_s:([0-9.]+) data_s:([0-9.]+)")
# A tqdm bar's state: description, percentage, count and timing, without the bar itself.
PROGRESS = re.compile(r"([A-Za-z][\w ()=.-]*:\s+\d+%)\|[^|]*\|\s*(\d+/\d+ \[[^\]]*\])")
# What the pipeline writes in the marker of its output folder (`lerobot_ccdp.datasets.ownership`).
CREATED_BY = "lerobot_ccdp.benchmark.pipeline"


class PipelineError(RuntimeError):
    """A stage's command failed; the message names the command and ends with its log."""


def real_path(path: str | Path) -> Path:
    """The one spelling of an output folder, for the stage stamps (which hash command lines): the real path,
    symlinks and `..` resolved, the same from every working directory, so a run from another checkout (a
    worktree) reuses the stages a run from this one finished. A path that names no folder (`~user` of no
    user, a symlink loop) is an argument error."""
    try:
        expanded = Path(path).expanduser()
    except RuntimeError:
        user = str(path).split("/", 1)[0].removeprefix("~")
        raise argparse.ArgumentTypeError(f"{path}: there is no user {user}; spell the path out") from None
    try:
        return expanded.resolve()
    except (RuntimeError, OSError):  # Python 3.11 raises RuntimeError for a loop, 3.13 OSError (ELOOP)
        raise argparse.ArgumentTypeError(
            f"{path}: a symlink in it loops; fix the link or choose another path"
        ) from None


def canonical(path: str | Path) -> Path:
    """The one spelling of a settings folder in the stamps: its real path, relative to the working directory
    when inside it, so every checkout spells its own settings alike (the stamps hash their content too)."""
    real = real_path(path)
    return real.relative_to(Path.cwd()) if real.is_relative_to(Path.cwd()) else real


def task_slug(task: str) -> str:
    """File name of a task's configs and recipe: DoorOpening-v0 -> door_opening,
    ObjectManipulation-lite-v0 -> object_manipulation_lite."""
    name = task.removesuffix("-v0")
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower().replace("-", "_")


def expand_tasks(names: list[str]) -> list[str]:
    """`--tasks` as given: task ids, or one group name of TASK_GROUPS."""
    return TASK_GROUPS[names[0]] if len(names) == 1 and names[0] in TASK_GROUPS else names


def read_json(path: Path) -> dict[str, Any]:
    """A settings file's JSON object; an error names the file."""
    try:
        content = json.loads(path.read_text())
    except ValueError as error:
        raise ValueError(f"{path} is not valid JSON: {error}") from None
    if not isinstance(content, dict):
        raise ValueError(f"{path} must hold a JSON object ({{...}}), not {type(content).__name__}")
    return content


@dataclass(frozen=True)
class TaskFiles:
    """A task's settings files and where its outputs go."""

    task: str
    recipe: Path
    train_base: Path
    train_recovery: Path
    eval: Path
    out: Path

    @classmethod
    def locate(
        cls,
        task: str,
        configs: Path,
        recipes: Path,
        out: Path,
        obs_type: str = "state",
        label_free: bool = False,
    ) -> TaskFiles:
        if task not in TASKS:
            raise ValueError(f"Unknown task {task!r}; choose among {', '.join(TASKS)}")
        slug = task_slug(task) + OBS_VARIANTS[obs_type] + (LABEL_FREE if label_free else "")
        files = cls(
            task,
            recipes / f"{slug}.yaml",
            configs / slug / "train_base.json",
            configs / slug / "train_recovery.json",
            configs / slug / "eval.json",
            out / slug,
        )
        settings = (files.recipe, files.train_base, files.train_recovery, files.eval)
        missing = [str(p) for p in settings if not p.is_file()]
        if missing:
            raise FileNotFoundError(
                f"{task}: missing settings file(s) {', '.join(missing)}; --configs and --recipes name the "
                "folders that hold them"
            )
        # Checked now, not when the stage that reads them runs, minutes or hours in.
        files.method_settings(METHODS[0])  # names unknown methods of methods.json
        RecordRecipe.load(files.recipe)
        RecoveryRecipe.load(files.recipe)
        config = files.eval_config()
        numbers = {  # name: (value, least)
            "eval.n_episodes": (config.get("eval", {}).get("n_episodes"), 1),
            "eval.batch_size": (config.get("eval", {}).get("batch_size", 1), 1),
            "seed": (config.get("seed", 0), 0),
        }
        for name, (value, least) in numbers.items():
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ValueError(f"{files.eval}: {name} must be an integer >= {least}, got {value!r}")
        env = config["env"]
        if env.get("task") != task:
            raise ValueError(f"{files.eval} evaluates env.task={env.get('task')!r}, not {task!r}")
        if env.get("obs_type", "state") != obs_type:
            raise ValueError(
                f"{files.eval} evaluates env.obs_type={env.get('obs_type', 'state')!r}, not {obs_type!r}"
            )
        files.recovery_head()  # the base config parses, and fits the env's inputs
        return files

    def eval_config(self) -> dict[str, Any]:
        return read_json(self.eval)

    def seeds(self, first: int | None = None, episodes: int | None = None) -> range:
        """The evaluation's seeds, episode i's at `first + i`: from `first` (None: the eval config's seed) for
        `episodes` episodes (None: the eval config's number)."""
        config = self.eval_config()
        first = config.get("seed", 1000) if first is None else first
        return range(first, first + (config["eval"]["n_episodes"] if episodes is None else episodes))

    def recovery_head(self) -> str:
        """The recovery head the base config builds (part of the checkpoint's architecture, so chosen there):
        the one train_base.json names, or the default lerobot-train names for the inputs of the task's env as
        eval.json sets it up (`heads.head_of`: the set denoiser without cameras). The classifier head trains
        on the demonstrations, the others on a synthesised recovery dataset."""
        policy = {k: v for k, v in read_json(self.train_base).get("policy", {}).items() if k != "type"}
        env = CCDPEnvConfig(**{k: v for k, v in self.eval_config()["env"].items() if k != "type"})
        features = env_to_policy_features(env)
        config = CCDPConfig(
            **policy,
            input_features={k: f for k, f in features.items() if f.type is not FeatureType.ACTION},
            output_features={k: f for k, f in features.items() if f.type is FeatureType.ACTION},
            device="cpu",
        )
        return head_of(config).name

    def method_settings(self, method: str) -> dict[str, Any]:
        """Policy fields with which `method` is evaluated, from the optional `methods.json` beside the eval
        config ({"dp_star": {"dp_star_candidates": 32}}): the baselines' own settings, which the shared
        checkpoint does not hold."""
        path = self.eval.with_name("methods.json")
        settings = read_json(path) if path.is_file() else {}
        unknown = sorted(set(settings) - set(METHODS))
        if unknown:
            raise ValueError(f"{path} names unknown method(s) {unknown}; its keys are among {list(METHODS)}")
        if method == "dp_star_matched" and method not in settings:
            return {**settings.get("dp_star", {}), **MATCHED_DP_STAR}
        return settings.get(method, {})

    def method_flags(self, method: str, overrides: dict[str, Any] | None = None) -> list[str]:
        """`method_settings`, with `overrides` on top (a setting being tuned), as lerobot-eval's `--policy.*`
        flags (booleans spelled as draccus reads them: true/false, not Python's True/False)."""
        settings = {**self.method_settings(method), **(overrides or {})}
        return [
            f"--policy.{key}={json.dumps(v) if isinstance(v, bool) else v}" for key, v in settings.items()
        ]

    def eval_command(
        self,
        checkpoint: Path,
        method: str,
        seed: int,
        out: Path,
        flags: list[str],
        videos: bool = False,
        episodes: int | None = None,
    ) -> list[str]:
        """lerobot-eval of `method` on `checkpoint` with this task's eval config, from `seed`, into `out`, on
        common random numbers (`COMMON_NOISE`): unrendered, or (`videos`) the first VIDEO_EPISODES episodes
        (at most the evaluated ones) rendered as the eval config says, in one batch. Episode i has seed
        `seed + i` and its row's noise stream whatever the batch size, so the rendered episodes are the
        evaluated ones (up to the floating-point differences of other batch sizes). `episodes` replaces the
        config's number of episodes (None: the config's, and the command names none)."""
        config = self.eval_config()["eval"]
        if videos:
            n = min(VIDEO_EPISODES, config["n_episodes"] if episodes is None else episodes)
            render = [f"--eval.n_episodes={n}", f"--eval.batch_size={n}"]
        else:
            render = ["--env.render_mode=null"]
            if episodes is not None:
                batch = min(config["batch_size"], episodes)
                render += [f"--eval.n_episodes={episodes}", f"--eval.batch_size={batch}"]
        return [
            "lerobot-eval",
            f"--config_path={self.eval}",
            f"--policy.path={checkpoint}",
            f"--policy.recovery_mode={RECOVERY_MODE[method]}",
            COMMON_NOISE,
            *flags,
            *render,
            f"--seed={seed}",
            f"--output_dir={out}",
        ]

    @property
    def demos(self) -> Path:
        return self.out / "demos"

    @property
    def recovery_data(self) -> Path:
        return self.out / "recovery_data"

    def eval_dir(self, method: str) -> Path:
        return self.out / "eval" / method

    def recovery_out(self, method: str = "ccdp") -> Path:
        """The recovery stage's folder of the head `method` samples (the task's own unless HEAD_METHODS
        names another)."""
        return self.out / f"recovery{HEAD_METHODS.get(method, HeadStages()).suffix}"

    def video_dir(self, method: str) -> Path:
        return self.out / "videos" / method


class TaskRun:
    """Runs one task's stages, skipping those whose output exists, and times each stage."""

    def __init__(
        self,
        files: TaskFiles,
        eval_seed: int | None = None,
        eval_episodes: int | None = None,
        jobs: int = 1,
        train_seed: int | None = None,
    ):
        self.files = files
        # None: the configs' and the recipe's own seeds, which no command then names (their stamps stay those
        # of the files); else every random draw of the training (both stages and the synthesis between them)
        self.seed_flags = [] if train_seed is None else [f"--seed={train_seed}"]
        self.synthesis_seed_flags = [] if train_seed is None else [f"--recovery.seed={train_seed}"]
        # Stages run `jobs` at a time (`run_at_once`, at most `jobs` commands at once), each with
        # `stage_threads(jobs)` torch threads.
        self.jobs = jobs
        self.slots = threading.Semaphore(jobs)
        self.threads = stage_threads(jobs)
        self._book_lock = threading.Lock()
        seeds = files.seeds(eval_seed, eval_episodes)
        self.eval_seed, self.n_episodes = seeds.start, len(seeds)
        # None: the eval config's number, which no command then names (its stamps stay those of the config)
        self.eval_episodes = eval_episodes
        self.slug = files.out.name
        self.logs = files.out / "logs"
        self.logs.mkdir(parents=True, exist_ok=True)
        self.stamps = StampBook(files.out / "stamps.json")
        timings_path = files.out / "timings.json"
        self.timings: dict[str, float] = json.loads(timings_path.read_text()) if timings_path.exists() else {}

    def run(self, methods: list[str], evaluate: bool = True) -> dict[str, Episodes]:
        """Every stage `methods` need, and (`evaluate`) their evaluations: the task's own head always, and
        the head of each method of another head (HEAD_METHODS)."""
        f = self.files
        demos = self._stage(
            "record",
            f.demos / "meta" / "info.json",
            [
                "lerobot-ccdp-record",
                f"--config_path={f.recipe}",
                f"--dataset.repo_id=local/{self.slug}",
                f"--dataset.root={f.demos}",
            ],
            upstream=None,
            clear=f.demos,
        )
        base, base_stamp = self._train(
            "train_base", f.train_base, f.out / "base", f"local/{self.slug}", f.demos, upstream=demos
        )

        def evaluations(checkpoint: Path, upstream: str, names: list[str]) -> list[Callable[[], str]]:
            """Each method's evaluation and videos stages on `checkpoint`."""
            stages = [(f"eval_{m}", m, f.eval_dir(m), False) for m in names] + [
                (f"videos_{m}", m, f.video_dir(m), True) for m in names if m in VIDEO_METHODS
            ]
            return [
                functools.partial(
                    self._stage,
                    stage,
                    out / "eval_info.json",
                    f.eval_command(
                        checkpoint,
                        method,
                        self.eval_seed,
                        out,
                        f.method_flags(method),
                        videos=videos,
                        episodes=self.eval_episodes,
                    ),
                    upstream=upstream,
                    clear=out,
                )
                for stage, method, out, videos in stages
            ]

        def head_lane(stages: HeadStages) -> Callable[[], None]:
            def lane() -> None:
                recovery, recovery_stamp = self._recovery(base, base_stamp, stages)
                sampled = [m for m in methods if HEAD_METHODS.get(m) == stages] if evaluate else []
                run_at_once(self.jobs, evaluations(recovery, recovery_stamp, sampled))

            return lane

        # The task's own head always (the checkpoint --train-only leaves for tune_methods), then each other
        # head a method samples. The baselines sample the base alone, so they are evaluated on the base's
        # checkpoint (a recovery checkpoint holds the same weights, frozen in its stage) while the heads are
        # made beside.
        heads = dict.fromkeys([HeadStages(), *(HEAD_METHODS[m] for m in methods if m in HEAD_METHODS)])
        baselines = [m for m in methods if m not in HEAD_METHODS] if evaluate else []
        run_at_once(self.jobs, [*map(head_lane, heads), *evaluations(base, base_stamp, baselines)])
        return self.episodes(methods) if evaluate and methods else {}

    def _recovery(self, base: Path, base_stamp: str, stages: HeadStages) -> tuple[Path, str]:
        """Synthesise the rows of the head of `stages` from `base` (unless the head learns from the
        demonstrations) and train the recovery stage on them; return its checkpoint and stamp."""
        f = self.files
        head = head_class(stages.head or f.recovery_head())
        # another head than the base config's: named at synthesis and training, and the settings only the
        # base's head reads returned to their defaults, which that head would refuse
        other = [] if stages.head is None else [f"--policy.recovery_head={head.name}"]
        data = f.out / f"recovery_data{stages.suffix}"
        if head.training_data == "demonstrations":  # nothing to synthesise
            recovery_repo, recovery_root, recovery_upstream = f"local/{self.slug}", f.demos, base_stamp
        else:
            recovery_repo, recovery_root = f"local/{self.slug}_recovery{stages.suffix}", data
            # the recipe's set-denoiser option, which no other head's rows carry
            unused = other and head.training_data != "base_samples"
            set_only = unused and RecoveryRecipe.load(f.recipe).demo_siblings
            siblings = ["--recovery.demo_siblings=false"] if set_only else []
            recovery_upstream = self._stage(
                f"synthesize{stages.suffix}",
                data / "meta" / "info.json",
                [
                    "lerobot-ccdp-synthesize",
                    f"--config_path={f.recipe}",
                    f"--dataset.repo_id=local/{self.slug}",
                    f"--dataset.root={f.demos}",
                    f"--policy.path={base}",
                    *other,
                    *siblings,
                    f"--output.repo_id={recovery_repo}",
                    f"--output.root={data}",
                    *self.synthesis_seed_flags,
                ],
                upstream=base_stamp,
                clear=data,
            )
        if other:
            other = [*other, *settings_of_other_heads(read_json(f.train_base).get("policy", {}), head.name)]
        return self._train(
            f"train_recovery{stages.suffix}",
            f.train_recovery,
            f.out / f"recovery{stages.suffix}",
            recovery_repo,
            recovery_root,
            f"--policy.path={base}",
            "--policy.training_stage=recovery",
            *other,
            upstream=recovery_upstream,
        )

    def episodes(self, methods: list[str]) -> dict[str, Episodes]:
        """Every method's evaluated episodes, and the oracle's on the same seeds (run here if missing)."""
        missing = [m for m in methods if not (self.files.eval_dir(m) / "eval_info.json").exists()]
        if missing:
            raise PipelineError(
                f"{self.files.task}: no evaluation of {missing} under {self.files.out / 'eval'}; "
                "run the pipeline without --report-only first."
            )
        episodes = {m: Episodes.from_eval_info(self.files.eval_dir(m) / "eval_info.json") for m in methods}
        stale = {m: len(e) for m, e in episodes.items() if len(e) != self.n_episodes}
        if stale:
            raise PipelineError(
                f"{self.files.task}: the evaluations of {stale} (episodes per method) are not of the "
                f"{self.n_episodes} episodes asked for (the eval config or --eval-episodes); run the "
                "pipeline without --report-only to evaluate them again."
            )
        episodes["oracle"] = self._oracle()
        return episodes

    def labels(self, methods: list[str]) -> dict[str, str]:
        """The name each method's figures carry."""
        return {m: METHOD_LABELS[m] for m in methods}

    def _train(
        self, stage: str, config: Path, out: Path, repo_id: str, root: Path, *extra: str, upstream: str
    ) -> tuple[Path, str]:
        checkpoint = out / CHECKPOINT
        stamp_value = self._stage(
            stage,
            checkpoint / "model.safetensors",
            [
                "lerobot-train",
                f"--config_path={config}",
                f"--dataset.repo_id={repo_id}",
                f"--dataset.root={root}",
                f"--output_dir={out}",
                *self.seed_flags,
                *extra,
            ],
            upstream=upstream,
            clear=out,
        )
        return checkpoint, stamp_value

    def _stage(
        self,
        name: str,
        output: Path,
        command: list[str],
        upstream: str | None,
        clear: Path,
    ) -> str:
        """Run `command` unless `output` exists and was made from the same inputs; return the stage's stamp.

        `clear` (the stage's own output folder, stale or half-written) is removed before the command runs;
        it must lie inside the task's folder, which lies in the --out this pipeline owns. The command runs in
        one of the task's `jobs` slots, with `stage_threads(jobs)` torch threads."""
        task_out = self.files.out.resolve()
        if clear.resolve() == task_out or not clear.resolve().is_relative_to(task_out):
            raise PipelineError(
                f"{self.files.task} {name}: refusing to clear {clear}, which is not inside "
                f"the task's output folder {self.files.out}; a stage clears only its own."
            )
        current = stamp(command, upstream)
        if output.exists() and self.stamps.matches(name, current):
            print(f"[{self.files.task}] {name}: done already ({output})", flush=True)
            return current
        if output.exists():
            print(
                f"[{self.files.task}] {name}: its inputs changed since {output} was made; running it again",
                flush=True,
            )
        if clear.exists():
            shutil.rmtree(clear)
        log = self.logs / f"{name}.log"
        print(f"[{self.files.task}] {name}: {shlex.join(command)}", flush=True)
        with self.slots:
            start = time.perf_counter()
            returncode = run_with_progress(
                [str(BIN / command[0]), *command[1:]],
                log,
                f"[{self.files.task}] {name}",
                threads=self.threads,
            )
        if returncode != 0 or not output.exists():
            tail = log.read_text()[-4000:]
            raise PipelineError(
                f"{self.files.task} {name} failed (exit {returncode}, expected {output}): "
                f"{shlex.join(command)}\n--- end of {log} ---\n{tail}"
            )
        with self._book_lock:  # stages side by side share the task's timings and stamps files
            self.timings[name] = round(time.perf_counter() - start, 1)
            (self.files.out / "timings.json").write_text(json.dumps(self.timings, indent=2))
            self.stamps.record(name, current)
        print(f"[{self.files.task}] {name}: {self.timings[name]:.0f} s", flush=True)
        return current

    def _oracle(self) -> Episodes:
        """The no-repeat oracle on lerobot-eval's seeds (episode i gets seed `seed + i`) and env settings.

        It reads the hidden state, never the observation, so cameras are not rendered for it."""
        path = self.files.out / "oracle.json"
        sized = [] if self.eval_episodes is None else [str(self.eval_episodes)]
        current = stamp(["oracle", str(self.files.eval), str(self.eval_seed), *sized], upstream=None)
        if not (path.exists() and self.stamps.matches("oracle", current)):
            config = self.files.eval_config()
            env_settings = {k: v for k, v in config["env"].items() if k != "type"}
            env_config = CCDPEnvConfig(**{**env_settings, "obs_type": "state"})
            env = gym.make(env_config.gym_id, **{**env_config.gym_kwargs, "render_mode": None})
            oracle = NoRepeatOracle(env)
            infos = [run_episode(env, oracle, seed=self.eval_seed + i).info for i in range(self.n_episodes)]
            path.write_text(json.dumps([{k: _plain(v) for k, v in i.items()} for i in infos]))
            self.stamps.record("oracle", current)
        return Episodes.from_infos(json.loads(path.read_text()))

    def step_times(self) -> dict[str, tuple[float, float]]:
        """(update s, data s) per step from the last log line of each training stage."""
        times = {}
        for log in sorted(self.logs.glob("train_*.log")):
            found = STEP_TIMES.findall(log.read_text())
            if found:
                times[log.stem] = tuple(float(v) for v in found[-1])
        return times


def settings_of_other_heads(policy: dict[str, Any], head: str) -> list[str]:
    """`--policy.*` flags that return the settings of `policy` (a base config's) that only another head than
    `head` reads to CCDPConfig's defaults: `head`, trained from that base, refuses them as settings that would
    do nothing (`refuse_settings_of_other_heads`)."""
    own, fields = set(head_class(head).own_settings), CCDPConfig.__dataclass_fields__
    names = dict.fromkeys(name for other in HEADS.values() for name in other.own_settings if name not in own)
    return [
        f"--policy.{name}={json.dumps(fields[name].default)}"
        for name in names
        if policy.get(name) is not None and policy[name] != fields[name].default
    ]


def stage_threads(jobs: int) -> int:
    """Torch threads of each stage's command: the machine's cores shared among the `jobs` commands that may
    run at once."""
    return max(1, (os.cpu_count() or 1) // jobs)


def run_at_once(jobs: int, calls: list[Callable[[], Any]]) -> None:
    """Run `calls` (independent stages), `jobs` at a time, in order. After a failure no further call starts,
    and the failure is raised once the calls already running have ended; an interrupt (Ctrl-C) kills the
    running stages' commands first, as one stage's own interrupt does (`run_with_progress`)."""
    failed = threading.Event()

    def guarded(call: Callable[[], Any]) -> None:
        if failed.is_set():
            return
        try:
            call()
        except BaseException:
            failed.set()
            raise

    if jobs == 1:
        for call in calls:
            call()
        return
    pool = ThreadPoolExecutor(max_workers=jobs)
    futures = [pool.submit(guarded, call) for call in calls]
    try:
        wait(futures, return_when=FIRST_EXCEPTION)
    except BaseException:
        failed.set()
        with _RUNNING_LOCK:
            for process in _RUNNING:
                process.kill()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    for future in futures:
        if not future.cancelled() and future.exception() is not None:
            raise future.exception()


# The stage commands running now, for `run_at_once` to kill on an interrupt.
_RUNNING: set[subprocess.Popen] = set()
_RUNNING_LOCK = threading.Lock()


def run_with_progress(
    command: list[str], log: Path, label: str, every: float = 15.0, threads: int | None = None
) -> int:
    """Run `command` with its output in `log`, printing its latest progress-bar state every `every` seconds
    (a training stage is otherwise silent on the console for minutes); return its exit code. `threads`, if
    given, caps the command's torch threads: several at once on few cores would otherwise oversubscribe them
    (2 cores: a training at 5 s/step beside two others, 0.25 s/step with one thread each)."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    if threads is not None:
        env.update(OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads))
    with log.open("w") as handle:
        process = subprocess.Popen(
            command,
            stdout=handle,
            stderr=subprocess.STDOUT,
            env=env,
            preexec_fn=functools.partial(die_with_parent, os.getpid()),  # noqa: PLW1509 (no locks)
        )
        with _RUNNING_LOCK:
            _RUNNING.add(process)
        shown = ""
        try:
            while True:
                try:
                    return process.wait(timeout=every)
                except subprocess.TimeoutExpired:
                    progress = latest_progress(log)
                    if progress and progress != shown:
                        print(f"{label}: {progress}", flush=True)
                        shown = progress
                except BaseException:
                    process.kill()  # an interrupted pipeline leaves no training running into its folder
                    raise
        finally:
            with _RUNNING_LOCK:
                _RUNNING.discard(process)


def latest_progress(log: Path) -> str:
    """The last tqdm state in a log (`Training:  45%|...| 360/800 [02:10<02:39, 2.76step/s]`), compacted."""
    with log.open("rb") as handle:
        handle.seek(max(log.stat().st_size - 4096, 0))
        tail = handle.read().decode(errors="replace")
    found = PROGRESS.findall(tail)
    return " ".join(" ".join(found[-1]).split()) if found else ""


def _plain(value: Any) -> Any:
    return value.item() if hasattr(value, "item") else value


def time_breakdown(runs: list[TaskRun]) -> str:
    """Seconds per stage and task, and how much of a training step is data loading. The sum counts stages
    that ran side by side (`--jobs`) each in full, so it exceeds the run's wall time, which the console's last
    line gives."""
    stages = list(dict.fromkeys(s for r in runs for s in r.timings))
    if not stages:
        return "No stage ran in this output folder (every output was given)."
    lines = ["| task | " + " | ".join(stages) + " | sum |", "|---|" + "---|" * (len(stages) + 1)]
    for r in runs:
        cells = [f"{r.timings[s]:.0f}" if s in r.timings else "-" for s in stages]
        lines.append(f"| {r.files.task} | " + " | ".join(cells) + f" | {sum(r.timings.values()):.0f} |")
    lines.append("")
    for r in runs:
        for stage, (update, data) in r.step_times().items():
            lines.append(
                f"- {r.files.task} {stage}: {update + data:.3f} s/step, data loading "
                f"{100 * data / (update + data):.0f}%"
            )
    return "\n".join(lines)


def method_forms(runs: list[TaskRun], episodes: dict[str, dict[str, Episodes]]) -> str:
    """Which form of each method ran: the seeds, and the settings of the evaluated checkpoint (the task's own
    head's, and that of each other head evaluated, on a row of its own), the recipe's synthesis and the
    methods' flags."""
    lines = [
        "| task | seeds | z | eq. (4) weights | sampler | synthesis (eq. 5, 7) | recovery steps | DP* |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r, (method, stages) in itertools.product(runs, HEAD_METHODS.items()):
        checkpoint = r.files.recovery_out(method) / CHECKPOINT / "config.json"
        if not checkpoint.is_file() or (stages.head and method not in episodes.get(r.files.task, {})):
            continue
        c = json.loads(checkpoint.read_text())
        n = r.n_episodes
        steps = json.loads(r.files.train_recovery.read_text()).get("steps")
        recipe = RecoveryRecipe.load(r.files.recipe)
        dp_star = {
            "dp_star_candidates": c["dp_star_candidates"],
            "dp_star_rounds": c.get("dp_star_rounds", CCDPConfig.dp_star_rounds),  # older checkpoints
            "delta_z": c["delta_z"],
            **r.files.method_settings("dp_star"),
        }
        # the checkpoint's settings, as the method's flags changed them
        ccdp = {**c, **r.files.method_settings(method)}
        head = head_class(ccdp["recovery_head"])  # named in every checkpoint (`heads.name_default_head`)
        pairs_delta_z = c["delta_z"] if recipe.delta_z is None else recipe.delta_z  # eq. (5)'s
        form = head.describe(ccdp)
        synthesis = {
            "demonstrations": f"none ({head.name} learns from the demos)",
            "base_samples": (
                f"chunks sampled half at option starts, half along the demos: sigma {recipe.sigma:g}, "
                f"w_s {recipe.w_s:g}, {recipe.n_states} x {recipe.chunks_per_state}"
            ),
            "recovery_pairs": f"delta_x {recipe.delta_x:g}, delta_z {pairs_delta_z:g}, w_s {recipe.w_s:g}",
        }[head.training_data]
        task = f"{r.files.task}, {METHOD_LABELS[method]}" if stages.head else r.files.task
        lines.append(
            f"| {task} | {r.eval_seed}-{r.eval_seed + n - 1} | {z_description(ccdp)} | {form} | "
            f"{c['noise_scheduler_type']} {c['num_inference_steps']} steps | {synthesis} | {steps} | "
            + (
                "- |"  # DP* samples the base, whose settings the task's own row gives
                if stages.head
                else f"{dp_star['dp_star_candidates']} candidates, "
                f"{dp_star['dp_star_rounds']} round(s), delta_z {dp_star['delta_z']:g} |"
            )
        )
    return "\n".join(lines)


def z_description(settings: dict[str, Any]) -> str:
    """What z was: the feature, for `action` which steps and dims, and for `final_state` which dims, where
    a failure's z was read and the set embedding's Fourier octaves."""
    if settings["failure_feature"] == "action":
        return "action: the attempt's first chunk"
    if settings["failure_feature"] == "primitive":
        at = settings.get("failure_label_at", CCDPConfig.failure_label_at)
        return "primitive" if at == "latest_chunk" else f"primitive, a failure's label read at {at}"
    if settings["failure_feature"] != "final_state":
        return settings["failure_feature"]
    dims = settings.get("failure_state_dims") or "all"
    at = settings.get("failure_state_at", "attempt_end")  # a checkpoint older than the field read it there
    segments = settings.get("failure_segments", CCDPConfig.failure_segments)
    ends = "" if segments == "labels" else f", demonstrated options end at {segments}"
    octaves = settings.get("z_fourier_octaves") or 0  # config.json holds the number (`validate_features`)
    ends += f", {octaves} Fourier octaves" if octaves else ""
    return f"final_state: state dims {dims}, a failure's read at {at}{ends}"


def machine() -> str:
    return (
        f"{platform.machine()}, {os.cpu_count()} CPU cores, torch {torch.__version__} "
        f"({torch.get_num_threads()} threads), Python {platform.python_version()}"
    )


def write_report(
    runs: list[TaskRun], episodes: dict[str, dict[str, Episodes]], out: Path, command: str, chart: bool
) -> str:
    results: Results = {
        task: {m: MethodMetrics.of(e) for m, e in methods.items()} for task, methods in episodes.items()
    }
    labels = {r.files.task: r.labels(list(episodes.get(r.files.task, {}))) for r in runs}
    parts = [
        "# CCDP vs DP vs DP* (paper Fig. 5)",
        f"Command: `{command}`  \nMachine: {machine()}",
        markdown_table(results, labels),
        "## What ran",
        "Seeds: episode i of every method and of the oracle uses seed `first + i`, and every method draws "
        "episode i's plans from the same noise (`--policy.row_noise_streams=true`, common random numbers). "
        "The CCDP row of the composition is eq. (4) as `lerobot_ccdp/policy/composition.py` computes it "
        "with the evaluated checkpoint's weights (`docs/method.md`).",
        method_forms(runs, episodes),
        "## Targets",
        "Judged from paired 95% intervals (same seeds for every method): `docs/evaluation.md`.",
        target_checks(episodes),
        "## Lost episodes",
        "Whether recovery or execution costs success: a lost episode repeated a failed option, or never had "
        "an attempt fail (the policy did not complete one before the time limit), or failed distinct options "
        "only. Before an episode's first failure DP, DP* and CCDP sample the same base policy from the same "
        "noise, so their episodes solved without a failure match up to floating-point differences of batched "
        "network calls, and recovery shows among the episodes with one.",
        lost_table(episodes, labels),
        "## Time per stage (s)",
        time_breakdown(runs),
    ]
    if chart:
        bar_chart(results, out / REPORT_FILES[3])
        parts.insert(3, "![comparison](comparison.png)")
    report = "\n\n".join(parts) + "\n"
    (out / REPORT_FILES[0]).write_text(report)
    summary = {
        task: {m: metrics.as_dict() for m, metrics in methods.items()} for task, methods in results.items()
    }
    (out / REPORT_FILES[1]).write_text(json.dumps(summary, indent=2))
    save_run(out / RUN_FILE, episodes, labels, command, runs[0].eval_seed if runs else 0)
    return report


def publish_report(report: str, out: Path, target: Path, flag: str = "--publish") -> None:
    """Copy the report (and its chart and per-episode run file, renamed after it) to `target`, so the docs
    show a run's own output and `lerobot_ccdp.benchmark.results` can tabulate it. Each of the three replaces
    only a file the pipeline published (`published.check_report_targets`, raising NotOwned before any is
    written), so a user's file of the same name is never lost."""
    chart = out / "comparison.png"
    check_report_targets(target, flag, chart=chart.exists())
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(out / RUN_FILE, target.with_suffix(".json"))
    if chart.exists():
        shutil.copyfile(chart, target.with_suffix(".png"))
        report = report.replace("](comparison.png)", f"]({target.with_suffix('.png').name})")
    note = f"{REPORT_NOTE} ({time.strftime('%Y-%m-%d')}); rerun it rather than editing. -->\n"
    target.write_text(note + report)


def run_tasks(
    files: list[TaskFiles], args: argparse.Namespace, command: str
) -> tuple[list[TaskRun], dict[str, dict[str, Episodes]]]:
    """Every task's stages (or, with --report-only, its finished evaluations), in order; with --publish-each,
    each task's own report is published as soon as its evaluations are done."""
    claim_output_folder(args.out, CREATED_BY, args.fresh, args.adopt)
    runs, episodes = [], {}
    for f in files:
        run = TaskRun(f, args.eval_seed, args.eval_episodes, args.jobs, args.train_seed)
        if args.report_only:
            episodes[f.task] = run.episodes(args.methods)
        else:
            episodes[f.task] = run.run(args.methods, evaluate=not args.train_only)
        runs.append(run)
        if episodes[f.task]:
            print(
                markdown_table({f.task: {m: MethodMetrics.of(e) for m, e in episodes[f.task].items()}}),
                flush=True,
            )
            if args.publish_each:
                target = args.publish_each / f"{f.task}.md"
                publish_report(
                    write_report([run], {f.task: episodes[f.task]}, f.out, command, not args.no_chart),
                    f.out,
                    target,
                    "--publish-each",
                )
                print(f"Published: {target}", flush=True)
    return runs, episodes


def published_reports(args: argparse.Namespace, tasks: list[str]) -> list[tuple[Path, str]]:
    """(path, flag) of every report the run will publish: --publish's, and --publish-each's per task."""
    if args.train_only:
        return []
    each = (
        [(args.publish_each / f"{task}.md", "--publish-each") for task in tasks] if args.publish_each else []
    )
    return ([(args.publish, "--publish")] if args.publish else []) + each


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--tasks",
        nargs="+",
        required=True,
        help=f"task ids, `all` (the five tasks: {', '.join(TASK_GROUPS['all'])}) or "
        "`lite` (their geometric versions, `<Task>-lite-v0`)",
    )
    parser.add_argument(
        "--methods",
        nargs="+",
        default=list(DEFAULT_METHODS),
        choices=METHODS,
        help=f"methods to evaluate (the no-repeat oracle always runs; default {' '.join(DEFAULT_METHODS)}). "
        f"{EPS_Z}: the paper's eq. (4) with the eps_z heads (recovery_head=unet), one sample per plan, "
        "synthesised and trained from the same base in stages of its own (synthesize_eps_z, "
        "train_recovery_eps_z) and evaluated with CCDP's sampling on the same seeds and noise; with "
        "--train-only, the heads of the methods named are trained",
    )
    parser.add_argument(
        "--out",
        type=real_path,
        default="outputs/pipeline",
        help=f"root of every output: a new or empty folder, or one this pipeline made (it holds {MARKER})",
    )
    parser.add_argument(
        "--configs", type=canonical, default="configs", help="folder of <task>/*.json configs"
    )
    parser.add_argument(
        "--recipes", type=canonical, default="datasets_recipes", help="folder of <task>.yaml recipes"
    )
    parser.add_argument(
        "--obs-type",
        choices=list(OBS_VARIANTS),
        default="state",
        help="policy inputs: state vectors, or rendered cameras plus the robot state",
    )
    parser.add_argument(
        "--label-free",
        action="store_true",
        help="run each task's <task>_label_free settings: z where an option ends, no labels read",
    )
    parser.add_argument("--no-chart", action="store_true", help="skip the PNG bar chart (needs matplotlib)")
    parser.add_argument(
        "--fresh",
        action="store_true",
        help="delete --out first instead of resuming (only a folder this pipeline made)",
    )
    parser.add_argument(
        "--adopt",
        action="store_true",
        help=f"mark an existing --out as this pipeline's ({MARKER}) and resume it: for an "
        "output folder made by a version of this pipeline from before the marker",
    )
    parser.add_argument(
        "--eval-seed",
        type=int,
        default=None,
        help="first evaluation seed (episode i gets seed + i); default: the eval config's, the test "
        "range. Tune settings on another range, e.g. the development seeds 1000-1099",
    )
    parser.add_argument(
        "--eval-episodes",
        type=int,
        default=None,
        help="episodes per method (seeds eval-seed ... eval-seed + N - 1); default: the eval config's, the "
        "test round's size. 100 with --eval-seed 1000 evaluates the development seeds",
    )
    parser.add_argument(
        "--publish",
        type=canonical,
        default=None,
        help="also write the report here (its run file and chart beside it, as .json and .png), e.g. "
        "docs/benchmark_report.md; a file already there is replaced only if the pipeline published it",
    )
    parser.add_argument(
        "--publish-each",
        type=canonical,
        default=None,
        help="also write each task's own report to <folder>/<task>.md (chart and run file beside it) as soon "
        "as its evaluations finish, so that a long round keeps every finished task's figures if it stops "
        "between tasks (rerun the others with --tasks); e.g. docs/benchmark. As --publish, it replaces only "
        "files the pipeline published",
    )
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="write the report from the evaluations already in --out, running no stage",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="evaluations of a task run side by side, each with cores / jobs torch threads: an evaluation's "
        "simulation runs on one core, which leaves the other idle while it steps (2 on 2 cores: 0.59 of the "
        "wall time of one at a time, same figures; each stage's time is then taken beside another: "
        "docs/benchmarks.md, Speed)",
    )
    parser.add_argument(
        "--train-seed",
        type=int,
        default=None,
        help="seed of the training: both lerobot-train stages' --seed and the synthesis' --recovery.seed "
        "(default: the configs' and recipe's, 0). One --out per training seed; compare trainings with "
        "python -m lerobot_ccdp.benchmark.pool_pairs",
    )
    parser.add_argument(
        "--train-only",
        action="store_true",
        help="record, train and synthesise (the task's own head, and that of each --methods method of "
        "another head), evaluate nothing and write no report (e.g. to tune a method's settings on the "
        "development seeds: python -m lerobot_ccdp.benchmark.tune_methods)",
    )
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs {args.jobs}: run at least one evaluation at a time")
    if args.eval_episodes is not None and args.eval_episodes < 1:
        parser.error(f"--eval-episodes {args.eval_episodes}: evaluate at least one episode per method")
    if args.fresh and args.report_only:
        parser.error("--fresh deletes the evaluations --report-only reports on; pass one of them")
    if args.train_only and args.report_only:
        parser.error("--train-only runs the training stages and --report-only runs none; pass one of them")
    if args.fresh and args.adopt:
        parser.error("--adopt keeps the folder's outputs and --fresh deletes them; pass one of them")
    if args.publish and args.publish.suffix != ".md":
        parser.error(
            f"--publish {args.publish}: name the report's .md file (its run file and chart go beside it, "
            "as .json and .png)"
        )
    tasks = expand_tasks(args.tasks)
    for flag, names in (("--tasks", tasks), ("--methods", args.methods)):
        twice = sorted({name for name in names if names.count(name) > 1})
        if twice:  # the same stage twice: with --jobs, two runs writing one folder at once
            parser.error(f"{flag} names {', '.join(twice)} more than once; name each once")
    try:
        files = [
            TaskFiles.locate(t, args.configs, args.recipes, args.out, args.obs_type, args.label_free)
            for t in tasks
        ]
    except (ValueError, OSError) as error:
        parser.error(str(error))
    for f in files:  # checked here: a stage clears its output before its command would refuse the seed
        seeds = f.seeds(args.eval_seed, args.eval_episodes)
        if len(seeds) > NUMPY_SEEDS:
            parser.error(
                f"--eval-episodes {len(seeds)}: more episodes than numpy has seeds (lerobot-eval seeds numpy "
                f"with each episode's own); evaluate at most {NUMPY_SEEDS}"
            )
        if seeds.start < 0 or seeds.stop > NUMPY_SEEDS:
            source = "--eval-seed" if args.eval_seed is not None else f"{f.eval}'s seed"
            parser.error(
                f"{source} {seeds.start}: its {len(seeds)} episodes would use seeds {seeds.start} to "
                f"{seeds.stop - 1}, outside numpy's seed range 0 to {NUMPY_SEEDS - 1} (lerobot-eval seeds "
                f"numpy with each); choose a first seed from 0 to {NUMPY_SEEDS - len(seeds)}"
            )
    command = command_line(
        "python -m lerobot_ccdp.benchmark.pipeline", argv if argv is not None else sys.argv[1:]
    )
    start = time.perf_counter()
    own = {folder / name for folder in [args.out, *(f.out for f in files)] for name in REPORT_FILES}
    for report, flag in published_reports(args, [f.task for f in files]):
        for copy in (report, report.with_suffix(".json"), report.with_suffix(".png")):
            if Path(os.path.realpath(copy)) in own:  # copied onto itself (after the whole run), or replaced
                parser.error(
                    f"{flag} {report} would publish onto {copy}, a file the pipeline writes there itself; "
                    "choose another name or folder"
                )
    try:
        for report, flag in published_reports(args, [f.task for f in files]):
            check_report_targets(report, flag, chart=not args.no_chart)
        check_output_folder(args.out, CREATED_BY, args.fresh, args.adopt)  # before the lock file beside it
        with exclusive(args.out):
            runs, episodes = run_tasks(files, args, command)
        if args.train_only:
            heads = dict.fromkeys(f.recovery_out(m) for f in files for m in ["ccdp", *args.methods])
            print(f"Trained: {', '.join(str(head / CHECKPOINT) for head in heads)}")
            return
        report = write_report(runs, episodes, args.out, command, chart=not args.no_chart)
        print(report)
        if args.publish:
            publish_report(report, args.out, args.publish)
            print(f"Published: {args.publish}")
    except (PipelineError, PipelineRunning, NotOwned) as error:
        sys.exit(str(error))
    print(f"Report: {args.out / 'report.md'}; wall time {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
