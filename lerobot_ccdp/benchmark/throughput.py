"""`python -m lerobot_ccdp.benchmark.throughput`: training steps per second of CCDP's base and recovery stages
beside LeRobot's own `diffusion` policy with the same UNet on the same demonstrations, through lerobot-train.

It reads a task's pipeline folder (`python -m lerobot_ccdp.benchmark.pipeline --train-only` or
`make quickstart` made it: demos, the base checkpoint, the recovery rows) and the task's train configs, trains
each of the three for `--steps` steps into a scratch folder, and prints steps/s and the share of a step spent
waiting for data, from lerobot-train's own `updt_s` / `data_s` log line. The three run one after another,
`--repeats` times interleaved, each with `--threads` torch threads, so that their ratios come from one run on
one machine. `--beside` keeps a low-priority busy process running meanwhile: a user's laptop is never idle,
and that light job decides how many threads a training may use (docs/benchmarks.md, Speed).
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import statistics
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from lerobot.utils.utils import init_logging

from lerobot_ccdp.benchmark.pipeline import (
    BIN,
    CHECKPOINT,
    STEP_TIMES,
    TaskFiles,
    canonical,
    read_json,
    real_path,
    run_with_progress,
)
from lerobot_ccdp.datasets.ownership import claim_output_folder

# The UNet and chunk fields LeRobot's DiffusionConfig shares with CCDPConfig: diffusion is built with the CCDP
# base's values, so that the two train the same network on the same windows.
SHARED_FIELDS = (
    "n_obs_steps",
    "horizon",
    "n_action_steps",
    "down_dims",
    "kernel_size",
    "n_groups",
    "diffusion_step_embed_dim",
    "use_film_scale_modulation",
    "num_train_timesteps",
    "beta_schedule",
    "prediction_type",
    "clip_sample",
    "clip_sample_range",
    "optimizer_lr",
)
RUNS = ("diffusion", "ccdp base", "ccdp recovery")


def run_dir(scratch: Path, name: str) -> Path:
    """Where run `name` trains (deleted before each repeat)."""
    return scratch / name.replace(" ", "_")


CREATED_BY = "lerobot_ccdp.benchmark.throughput"


@dataclass(frozen=True)
class StepTime:
    update_s: float
    data_s: float

    @property
    def steps_per_s(self) -> float:
        return 1.0 / (self.update_s + self.data_s)

    @property
    def data_share(self) -> float:
        return self.data_s / (self.update_s + self.data_s)


def diffusion_flags(base_config: dict) -> list[str]:
    """`--policy.*` flags that build LeRobot's diffusion with the CCDP base's UNet and windows."""
    flags = ["--policy.type=diffusion", "--policy.push_to_hub=false", "--policy.device=cpu"]
    for name in SHARED_FIELDS:
        value = base_config[name]
        if isinstance(value, list | tuple):
            value = "[" + ",".join(str(v) for v in value) + "]"
        elif isinstance(value, bool):
            value = json.dumps(value)
        flags.append(f"--policy.{name}={value}")
    # diffusion holds this as a field; CCDPConfig derives it from the same three numbers.
    drop = base_config["horizon"] - base_config["n_action_steps"] - base_config["n_obs_steps"] + 1
    return [*flags, f"--policy.drop_n_last_frames={drop}"]


def train_commands(files: TaskFiles, scratch: Path, steps: int, workers: int) -> dict[str, list[str]]:
    """The lerobot-train command of each run, `steps` long with one log line at its end."""
    base = files.out / "base" / CHECKPOINT
    demos, slug = files.demos, files.out.name
    needed = (demos / "meta" / "info.json", base, files.recovery_data / "meta" / "info.json")
    missing = [str(p) for p in needed if not p.exists()]
    if missing:
        raise FileNotFoundError(
            f"{files.task}: {', '.join(missing)} not found; make them first with `python -m "
            f"lerobot_ccdp.benchmark.pipeline --tasks {files.task} --train-only --out <run>` and pass that "
            "--run"
        )
    common = [f"--steps={steps}", f"--log_freq={steps}", f"--save_freq={steps}", f"--num_workers={workers}"]
    base_train = read_json(files.train_base)
    data = [f"--dataset.repo_id=local/{slug}", f"--dataset.root={demos}"]
    return {
        "diffusion": [
            "lerobot-train",
            *data,
            *diffusion_flags(read_json(base / "config.json")),
            f"--batch_size={base_train.get('batch_size', 8)}",
            "--wandb.enable=false",
            f"--output_dir={run_dir(scratch, 'diffusion')}",
            *common,
        ],
        "ccdp base": [
            "lerobot-train",
            f"--config_path={files.train_base}",
            *data,
            f"--output_dir={run_dir(scratch, 'ccdp base')}",
            *common,
        ],
        "ccdp recovery": [
            "lerobot-train",
            f"--config_path={files.train_recovery}",
            f"--dataset.repo_id=local/{slug}_recovery",
            f"--dataset.root={files.recovery_data}",
            f"--policy.path={base}",
            "--policy.training_stage=recovery",
            f"--output_dir={run_dir(scratch, 'ccdp recovery')}",
            *common,
        ],
    }


def measure(command: list[str], out: Path, log: Path, threads: int) -> StepTime:
    """Run one training and read its step time from lerobot-train's last log line."""
    shutil.rmtree(out, ignore_errors=True)
    code = run_with_progress([str(BIN / command[0]), *command[1:]], log, command[0], threads=threads)
    found = STEP_TIMES.findall(log.read_text())
    if code != 0 or not found:
        raise RuntimeError(f"{' '.join(command)} failed (exit {code}); its log: {log}")
    return StepTime(*(float(v) for v in found[-1]))


@contextmanager
def busy_beside(on: bool) -> Iterator[None]:
    """With `on`, a busy loop at the lowest priority (nice 19) runs until the block ends."""
    if not on:
        yield
        return
    job = subprocess.Popen(["nice", "-n", "19", sys.executable, "-c", "while True: pass"])
    try:
        yield
    finally:
        job.kill()
        job.wait()


def table(times: dict[str, list[StepTime]]) -> str:
    """Median over repeats of steps/s and data share, and each run's cost per step against diffusion's."""
    median = {
        name: StepTime(statistics.median(t.update_s for t in runs), statistics.median(t.data_s for t in runs))
        for name, runs in times.items()
    }
    reference = 1.0 / median["diffusion"].steps_per_s
    lines = ["| run | steps/s | data loading | s/step vs diffusion |", "|---|---|---|---|"]
    for name, t in median.items():
        cost = (1.0 / t.steps_per_s) / reference
        lines.append(f"| {name} | {t.steps_per_s:.2f} | {t.data_share:.0%} | {cost:.2f}x |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="DoorOpening-v0")
    parser.add_argument("--run", type=real_path, required=True, help="the pipeline's --out of a trained task")
    parser.add_argument("--configs", type=canonical, default="configs")
    parser.add_argument("--recipes", type=canonical, default="datasets_recipes")
    parser.add_argument("--out", type=real_path, default="outputs/throughput", help="scratch folder")
    parser.add_argument("--steps", type=int, default=200, help="training steps per run (>= 20)")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved repeats of the three runs")
    parser.add_argument("--threads", type=int, default=1, help="torch threads per run (OMP_NUM_THREADS)")
    parser.add_argument("--num-workers", type=int, default=0, help="lerobot-train's --num_workers")
    parser.add_argument(
        "--beside", action="store_true", help="a busy process at nice 19 runs beside every training"
    )
    args = parser.parse_args(argv)
    if args.steps < 20 or args.repeats < 1 or args.threads < 1 or args.num_workers < 0:
        parser.error("--steps >= 20, --repeats >= 1, --threads >= 1 and --num-workers >= 0")
    init_logging()
    files = TaskFiles.locate(args.task, args.configs, args.recipes, args.run)
    commands = train_commands(files, args.out / "train", args.steps, args.num_workers)
    claim_output_folder(args.out, CREATED_BY)  # its trainings are deleted between repeats: never a user's
    times: dict[str, list[StepTime]] = {name: [] for name in RUNS}
    with busy_beside(args.beside):
        for repeat in range(args.repeats):
            for name in RUNS:
                log = args.out / f"{run_dir(Path(), name)}_{repeat}.log"
                t = measure(commands[name], run_dir(args.out / "train", name), log, args.threads)
                logging.info(f"{name} ({repeat}): {t.steps_per_s:.2f} steps/s, data {t.data_share:.0%}")
                times[name].append(t)
    beside = ", a busy process beside" if args.beside else ""
    print(
        f"{args.task}, {args.steps} steps per run, {args.repeats} repeats, {args.threads} thread(s), "
        f"{args.num_workers} data worker(s){beside}:\n{table(times)}"
    )


if __name__ == "__main__":
    main()
