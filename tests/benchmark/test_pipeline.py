"""The main job end to end through the real CLIs, reduced (tiny steps, one task, a few episodes): every
stage's outputs exist, load, and feed the next; the report and a resumed run agree."""

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
import torch
import yaml
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils.constants import OBS_IMAGES
from PIL import Image

from lerobot_ccdp.benchmark.comparison import Episodes
from lerobot_ccdp.benchmark.paired import paired_difference, success_rate
from lerobot_ccdp.benchmark.pipeline import (
    CHECKPOINT,
    COMMON_NOISE,
    VIDEO_METHODS,
    PipelineError,
    TaskFiles,
    TaskRun,
    latest_progress,
    main,
    task_slug,
    z_description,
)
from lerobot_ccdp.benchmark.results import README_BEGIN, README_END, Run
from lerobot_ccdp.benchmark.run_lock import exclusive
from lerobot_ccdp.benchmark.stage_stamps import stamp
from lerobot_ccdp.datasets.camera_windows import video_backend
from lerobot_ccdp.policy.configuration_ccdp import FAILURE_FEATURE_KEY
from lerobot_ccdp.policy.heads.set_denoiser import w_z_window
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

REPO = Path(__file__).resolve().parents[2]
TASK = "DoorOpening-lite-v0"
SLUG = task_slug(TASK)
METHODS = ["dp", "ccdp"]
N_DEMOS, N_EPISODES = 8, 4
EVAL_SEED = 3000  # not the configs' test range: --eval-seed must reach lerobot-eval and the oracle


def _shrink_json(src: Path, dst: Path, changes: dict) -> None:
    config = json.loads(src.read_text())
    for key, value in changes.items():
        config[key] = {**config[key], **value} if isinstance(value, dict) else value
    dst.write_text(json.dumps(config))


def _shrunk_settings(root: Path, slug: str, n_episodes: int = N_EPISODES) -> tuple[Path, Path]:
    """The repository's configs and recipe of `slug`, shrunk to seconds per stage."""
    configs, recipes = root / "configs", root / "recipes"
    (configs / slug).mkdir(parents=True)
    recipes.mkdir()
    train = {"steps": 10, "batch_size": 8, "save_freq": 10, "log_freq": 5}
    # Episodes of 50 steps, not 150: the oracle needs at most 37 here (two attempts); an untrained policy uses
    # all. One batch, as the video rerun's: a batch of another size differs in floating point, which can flip
    # a close episode, and the rerun is compared episode by episode.
    evaluation = {"env": {"episode_length": 50}, "eval": {"n_episodes": n_episodes, "batch_size": n_episodes}}
    for name, changes in {"train_base": train, "train_recovery": train, "eval": evaluation}.items():
        _shrink_json(REPO / "configs" / slug / f"{name}.json", configs / slug / f"{name}.json", changes)
    recipe = yaml.safe_load((REPO / "datasets_recipes" / f"{slug}.yaml").read_text())
    recipe["record"]["n_episodes"] = N_DEMOS
    # RecoveryRecipe refuses unknown keys
    recipe["recovery"].update(
        {"n_states": 8, "chunks_per_state": 4, "batch_states": 8, "pairs_per_failure": 4, "demo_frames": 64}
    )
    (recipes / f"{slug}.yaml").write_text(yaml.safe_dump(recipe))
    return configs, recipes


@pytest.fixture(scope="module")
def settings(tmp_path_factory) -> tuple[Path, Path]:
    configs, recipes = _shrunk_settings(tmp_path_factory.mktemp("settings"), SLUG)
    # DP*'s own repeat threshold, which the report must name rather than the checkpoint's, and a CCDP sampling
    # setting that lerobot-eval must accept as a flag
    (configs / SLUG / "methods.json").write_text(
        json.dumps({"dp_star": {"dp_star_candidates": 32, "delta_z": 0.3}, "ccdp": {"w_z": 2.0}})
    )
    return configs, recipes


def _pipeline_command(
    configs: Path, recipes: Path, out: Path, *extra: str, methods: list[str] = METHODS
) -> list[str]:
    """The pipeline as a user runs it, on the shrunk settings and the module's task and seeds."""
    return [
        *(sys.executable, "-m", "lerobot_ccdp.benchmark.pipeline", "--tasks", TASK, "--methods", *methods),
        *("--out", str(out), "--configs", str(configs), "--recipes", str(recipes)),
        *("--eval-seed", str(EVAL_SEED), *extra),
    ]


def _run_pipeline(configs: Path, recipes: Path, out: Path, *extra: str, methods: list[str] = METHODS) -> str:
    command = _pipeline_command(configs, recipes, out, *extra, methods=methods)
    result = subprocess.run(command, capture_output=True, text=True, cwd=REPO)
    if result.returncode != 0:
        pytest.fail(
            f"pipeline failed ({result.returncode}):\n{result.stdout[-3000:]}\n{result.stderr[-6000:]}"
        )
    return result.stdout


@pytest.fixture(scope="module")
def pipeline_run(settings, tmp_path_factory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("pipeline")
    return out, _run_pipeline(
        *settings, out, "--publish", str(out / "docs" / "benchmark.md"), "--publish-each", str(out / "each")
    )


def test_every_stage_output_loads_and_feeds_the_next(pipeline_run):
    out, _ = pipeline_run
    task_out = out / SLUG

    demos = LeRobotDataset(f"local/{SLUG}", root=task_out / "demos")
    assert demos.meta.total_episodes == N_DEMOS

    base = CCDPPolicy.from_pretrained(task_out / "base" / CHECKPOINT)
    assert base.config.training_stage == "base" and not bool(base.model.recovery_trained)
    assert base.config.failure_feature == "primitive" and base.config.num_primitives == 2

    recovery_data = LeRobotDataset(f"local/{SLUG}_recovery", root=task_out / "recovery_data")
    row = recovery_data[0]
    assert row[FAILURE_FEATURE_KEY].shape == (base.config.failure_feature_dim,)
    assert row["action"].shape == (base.config.horizon, 4)
    source = yaml.safe_load((task_out / "recovery_data" / "meta" / "ccdp_recovery_recipe.yaml").read_text())
    assert source["source"]["policy_path"] == str(task_out / "base" / CHECKPOINT)  # made from this base

    recovery = CCDPPolicy.from_pretrained(task_out / "recovery" / CHECKPOINT)
    assert bool(recovery.model.recovery_trained)
    # the recovery stage starts from the base and freezes it
    for name, weight in base.model.base.state_dict().items():
        assert torch.equal(weight, recovery.model.base.state_dict()[name]), name

    for method in METHODS:
        episodes = Episodes.from_eval_info(task_out / "eval" / method / "eval_info.json")
        assert len(episodes) == N_EPISODES
        # One-stage task: every attempt after the first follows a failure (the env's count reached
        # eval_info.json).
        assert (episodes.attempts_after_failure == np.maximum(episodes.attempts - 1, 0)).all()
        assert not list((task_out / "eval" / method).rglob("*.mp4"))  # timed evaluations render nothing
        rendered = task_out / "videos" / method  # what lerobot_ccdp.benchmark.watch shows, made apart
        assert len(list(rendered.rglob("eval_episode_*.mp4"))) == (
            N_EPISODES if method in VIDEO_METHODS else 0
        )
        if method in VIDEO_METHODS:  # the same episodes as the evaluation's: seeds and noise streams
            again = Episodes.from_eval_info(rendered / "eval_info.json")
            assert (again.success == episodes.success).all() and (again.attempts == episodes.attempts).all()
    oracle = Episodes.from_infos(json.loads((task_out / "oracle.json").read_text()))
    assert len(oracle) == N_EPISODES and oracle.success.all() and not oracle.repeated_failures.any()


def test_report_table_chart_and_timings(pipeline_run):
    out, stdout = pipeline_run
    report = (out / "report.md").read_text()
    for label in (
        "| DoorOpening-lite-v0 | DP |",
        "| DoorOpening-lite-v0 | CCDP |",
        "| DoorOpening-lite-v0 | no-repeat oracle |",
        "success > DP",
        "attempts within 15% of oracle",
        "data loading",
    ):
        assert label in report, label
    assert report.split("## Targets")[0] in stdout  # the table is printed too
    # the form of the method that ran, and the seeds
    form = report.split("## What ran")[1].split("## Targets")[0]
    assert (
        f"| {TASK} | {EVAL_SEED}-{EVAL_SEED + N_EPISODES - 1} | primitive | w_h 0, w_z 2 against eps_z_null |"
    ) in form
    assert "| 32 candidates, 4 round(s), delta_z 0.3 |" in form
    assert "--policy.w_z=2.0" in stdout
    # each method's lost episodes, by cause
    lost = report.split("## Lost episodes")[1].split("## Time per stage")[0]
    for method in METHODS:
        episodes = Episodes.from_eval_info(out / SLUG / "eval" / method / "eval_info.json")
        assert f"| {TASK} | {method.upper()} | {(~episodes.success).sum()}: " in lost
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary[TASK]) == {*METHODS, "oracle"}
    assert summary[TASK]["oracle"]["success"]["value"] == 1.0
    assert (out / "comparison.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    published = (out / "docs" / "benchmark.md").read_text()
    assert published.split("\n", 1)[1] == report.replace("](comparison.png)", "](benchmark.png)")
    assert (out / "docs" / "benchmark.png").read_bytes() == (out / "comparison.png").read_bytes()
    # --publish-each: the task's own report (here the only task's, so the same), chart and run file
    each = (out / "each" / f"{TASK}.md").read_text()
    assert each.split("\n", 1)[1] == report.replace("](comparison.png)", f"]({TASK}.png)")
    assert (out / "each" / f"{TASK}.png").read_bytes() == (out / SLUG / "comparison.png").read_bytes()
    assert (out / "each" / f"{TASK}.json").read_text() == (out / "docs" / "benchmark.json").read_text()
    assert f"Published: {out / 'each' / TASK}.md" in stdout.split("## What ran")[0]  # before the last report
    for method in METHODS:  # lerobot-eval logs its config: the seed it was given
        assert f"'seed': {EVAL_SEED}," in (out / SLUG / "logs" / f"eval_{method}.log").read_text()
    timings = json.loads((out / SLUG / "timings.json").read_text())
    assert set(timings) == {
        "record",
        "train_base",
        "synthesize",
        "train_recovery",
        *(f"eval_{m}" for m in METHODS),
        *(f"videos_{m}" for m in METHODS),  # both test methods are watched
    }


def test_results_tabulate_the_published_run_file(pipeline_run, tmp_path):
    out, _ = pipeline_run
    run = Run.load(out / "docs" / "benchmark.json")  # published beside the report
    assert run.first_seeds == {TASK: EVAL_SEED} and run.labels[TASK]["ccdp"] == "CCDP"
    evaluated = {m: Episodes.from_eval_info(out / SLUG / "eval" / m / "eval_info.json") for m in METHODS}
    for method, episodes in evaluated.items():
        assert (run.episodes[TASK][method].success == episodes.success).all()
        assert (run.episodes[TASK][method].failures == episodes.failures).all()
    readme = tmp_path / "README.md"
    readme.write_text(f"# Title\n\n{README_BEGIN}\nold table\n{README_END}\n\nmore\n")
    results = tmp_path / "results.md"
    command = [
        sys.executable,
        "-m",
        "lerobot_ccdp.benchmark.results",
        "--run",
        "Lite door",
        str(out / "docs" / "benchmark.json"),
    ]
    subprocess.run([*command, "--out", str(results), "--readme", str(readme)], check=True, cwd=REPO)
    text = results.read_text()
    gap = paired_difference(evaluated["ccdp"], evaluated["dp"], success_rate)
    header = next(line for line in text.splitlines() if line.startswith("| task |"))
    row = next(line for line in text.splitlines() if line.startswith("| DoorOpening-lite |"))
    assert header == "| task | DP | CCDP | CCDP - DP |"  # only the methods that ran
    assert row.split(" | ")[1].startswith(f"{evaluated['dp'].success.mean():.2f} / ")
    assert row.split(" | ")[3] == f"{gap} |" and "## Lite door" in text
    assert "python -m lerobot_ccdp.benchmark.results --run" in text  # the command that wrote it
    assert row in readme.read_text() and "old table" not in readme.read_text()


def test_watch_shows_both_methods_on_the_same_rendered_episode(pipeline_run, tmp_path):
    out, _ = pipeline_run
    gif = tmp_path / "watch.gif"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "lerobot_ccdp.benchmark.watch",
            "--eval-root",
            str(out / SLUG / "videos"),
            "--episode",
            "1",
            "--out",
            str(gif),
        ],
        check=True,
        cwd=REPO,
    )
    with Image.open(gif) as image:
        # two 160x120 panels, titled
        assert image.n_frames > 5 and image.width > 2 * 160 and image.height > 120


def test_a_second_run_resumes_every_stage_however_the_folder_is_spelled(settings, pipeline_run, tmp_path):
    out, _ = pipeline_run
    summary = (out / "summary.json").read_text()
    # the stages' commands name the folder's real path, as the first run did
    (tmp_path / "link").symlink_to(out)
    stdout = _run_pipeline(*settings, tmp_path / "link")
    assert stdout.count("done already") == 4 + 2 * len(METHODS)  # and each watched method's video run
    assert (out / "summary.json").read_text() == summary


def test_train_only_stops_before_the_evaluations_and_the_report(settings, pipeline_run):
    out, _ = pipeline_run
    report = (out / "report.md").read_text()
    (out / SLUG / "oracle.json").rename(out / "oracle.json.kept")
    try:
        stdout = _run_pipeline(*settings, out, "--train-only")
        assert stdout.count("done already") == 4  # record, base, synthesis, recovery
        assert "eval_" not in stdout and not (out / SLUG / "oracle.json").exists()
        assert f"Trained: {out / SLUG / 'recovery' / CHECKPOINT}" in stdout
        assert (out / "report.md").read_text() == report
    finally:
        (out / "oracle.json.kept").rename(out / SLUG / "oracle.json")


# About 80 s each on a slower 2-core machine; in the default suite the stamps' rule is
# test_stamps_follow_settings_files_and_upstream_stages and the faked stages of test_pipeline_safety.py.
@pytest.mark.slow
def test_a_changed_config_reruns_its_stage_and_those_after_it(settings, pipeline_run):
    out, _ = pipeline_run
    configs, _ = settings
    recovery_config = configs / SLUG / "train_recovery.json"
    _shrink_json(recovery_config, recovery_config, {"steps": 12, "save_freq": 12})
    base_weights = (out / SLUG / "base" / CHECKPOINT / "model.safetensors").read_bytes()
    stdout = _run_pipeline(configs, settings[1], out, methods=["ccdp"])  # dp's runs would add nothing
    assert stdout.count("done already") == 3  # record, base, synthesis
    assert stdout.count("its inputs changed") == 3
    for stage in ("train_recovery", "eval_ccdp", "videos_ccdp"):
        assert f"{stage}: its inputs changed" in stdout
    assert (out / SLUG / "base" / CHECKPOINT / "model.safetensors").read_bytes() == base_weights
    step = json.loads(
        (
            out / SLUG / "recovery" / "checkpoints" / "last" / "training_state" / "training_step.json"
        ).read_text()
    )
    assert step["step"] == 12


@pytest.mark.slow
def test_a_method_setting_reruns_only_that_method_with_its_flags(settings, pipeline_run):
    out, _ = pipeline_run
    configs, recipes = settings
    methods = configs / SLUG / "methods.json"
    methods.write_text(json.dumps({**json.loads(methods.read_text()), "dp": {"dp_star_rounds": 2}}))
    try:
        stdout = _run_pipeline(configs, recipes, out)
    finally:
        methods.unlink()
    assert "eval_dp: its inputs changed" in stdout and "--policy.dp_star_rounds=2" in stdout
    assert "eval_ccdp: done already" in stdout


def test_method_settings_name_known_methods(tmp_path):
    # the module's settings hold a methods.json
    configs, recipes = _shrunk_settings(tmp_path / "settings", SLUG)
    files = TaskFiles.locate(TASK, configs, recipes, tmp_path)
    assert files.method_flags("dp_star") == []  # no methods.json: the checkpoint's settings
    (configs / SLUG / "methods.json").write_text(
        json.dumps({"dp_star": {"dp_star_candidates": 32}, "DP": {}})
    )
    with pytest.raises(ValueError, match=r"unknown method\(s\) \['DP'\]"):
        files.method_flags("dp_star")


def test_the_compute_matched_baseline_is_dp_star_with_few_candidates(tmp_path):
    """`dp_star_matched` evaluates recovery_mode=dp_star with 2 candidates and 1 round unless methods.json
    names its own, beside (not instead of) DP*'s tuned settings, and reads a failure's z as DP* does."""
    configs, recipes = _shrunk_settings(tmp_path / "settings", SLUG)
    dp_star = {"dp_star_candidates": 32, "failure_state_at": "demonstrated_end", "delta_z": 0.05}
    (configs / SLUG / "methods.json").write_text(json.dumps({"dp_star": dp_star}))
    files = TaskFiles.locate(TASK, configs, recipes, tmp_path)
    command = files.eval_command(
        Path("ck"), "dp_star_matched", 1000, tmp_path, files.method_flags("dp_star_matched")
    )
    assert "--policy.recovery_mode=dp_star" in command
    assert {"--policy.dp_star_candidates=2", "--policy.dp_star_rounds=1"} <= set(command)
    assert {"--policy.failure_state_at=demonstrated_end", "--policy.delta_z=0.05"} <= set(command)
    assert "--policy.dp_star_candidates=32" not in command
    assert "--policy.dp_star_candidates=32" in files.method_flags("dp_star")
    own = {"dp_star_candidates": 4, "dp_star_rounds": 1}
    (configs / SLUG / "methods.json").write_text(json.dumps({"dp_star": dp_star, "dp_star_matched": own}))
    assert files.method_flags("dp_star_matched") == [
        "--policy.dp_star_candidates=4",
        "--policy.dp_star_rounds=1",
    ]
    # a boolean setting as draccus parses it (it refuses Python's "True")
    assert files.method_flags("ccdp", {"clip_sample": False}) == ["--policy.clip_sample=false"]


def test_every_timed_evaluation_is_unrendered_and_videos_are_a_run_of_their_own(settings, tmp_path):
    """Evaluation times compare methods, so none renders (videos of the Panda scene cost minutes); the videos
    `watch` shows come from a short rendered run of the same first episodes."""
    files = TaskFiles.locate(TASK, *settings, tmp_path)
    for method in ("dp", "dp_star", "ccdp"):
        command = files.eval_command(Path("checkpoint"), method, 0, tmp_path / method, [])
        assert "--env.render_mode=null" in command, method
        assert COMMON_NOISE in command  # every method on the same noise streams
        assert command[-2:] == ["--seed=0", f"--output_dir={tmp_path / method}"]
        videos = files.eval_command(Path("checkpoint"), method, 0, tmp_path / method, [], videos=True)
        assert "--env.render_mode=null" not in videos and f"--eval.n_episodes={N_EPISODES}" in videos


def test_eval_episodes_sizes_every_evaluation_and_the_oracle_and_is_named_only_when_given(
    settings, tmp_path, capsys
):
    """`--eval-episodes`: development evaluations of their own size where the eval config sizes a test round;
    without it no command names a size, so a round's stamps stay those of its eval config."""
    files = TaskFiles.locate(TASK, *settings, tmp_path)
    plain = files.eval_command(Path("checkpoint"), "ccdp", 0, tmp_path, [])
    assert not any(arg.startswith("--eval.") for arg in plain)
    sized = files.eval_command(Path("checkpoint"), "ccdp", 0, tmp_path, [], episodes=2)
    assert {"--eval.n_episodes=2", "--eval.batch_size=2"} <= set(sized)  # the config's batch is 4
    videos = files.eval_command(Path("checkpoint"), "ccdp", 0, tmp_path, [], videos=True, episodes=2)
    assert "--eval.n_episodes=2" in videos and "--env.render_mode=null" not in videos
    run = TaskRun(files, EVAL_SEED, 2)
    assert run.n_episodes == 2 and len(run._oracle()) == 2
    assert TaskRun(files, EVAL_SEED).n_episodes == N_EPISODES
    with pytest.raises(SystemExit):
        main(["--tasks", TASK, "--out", str(tmp_path / "out"), "--eval-episodes", "0"])
    assert "--eval-episodes 0: evaluate at least one episode" in capsys.readouterr().err
    # --report-only names evaluations of another size rather than reporting them under this size's seeds
    files.eval_dir("dp").mkdir(parents=True)
    metrics = {key: [1] * 3 for key in ("successes", "attempts", "repeated_failures", "preference_matched")}
    (files.eval_dir("dp") / "eval_info.json").write_text(json.dumps({"per_task": [{"metrics": metrics}]}))
    with pytest.raises(PipelineError, match=r"evaluations of \{'dp': 3\}.*not of the 2 episodes"):
        run.episodes(["dp"])


def test_stamps_follow_settings_files_and_upstream_stages(tmp_path):
    config = tmp_path / "train.json"
    config.write_text('{"steps": 10}')
    command = ["lerobot-train", f"--config_path={config}", "--output_dir=x"]
    first = stamp(command, upstream="a")
    assert stamp(command, upstream="a") == first
    assert stamp(command, upstream="b") != first  # a rerun upstream stage reruns this one
    config.write_text('{"steps": 11}')
    assert stamp(command, upstream="a") != first  # so does an edited config


def test_console_progress_is_the_latest_bar_state_of_the_log(tmp_path):
    log = tmp_path / "train.log"
    log.write_text(
        "INFO start\rTraining:  10%|█         | 80/800 [00:30<04:30,  2.66step/s]"
        "\rTraining:  11%|█▏        | 88/800 [00:33<04:27,  2.66step/s]\nINFO step:88 loss:0.1"
    )
    assert latest_progress(log) == "Training: 11% 88/800 [00:33<04:27, 2.66step/s]"
    log.write_text("no bar yet")
    assert latest_progress(log) == ""


def test_a_second_pipeline_on_the_same_folder_is_refused(settings, tmp_path):
    configs, recipes = settings
    with (
        exclusive(tmp_path / "out"),
        pytest.raises(SystemExit, match=r"Another pipeline \(pid \d+\) is running"),
    ):
        main(
            [
                "--tasks",
                TASK,
                "--out",
                str(tmp_path / "out"),
                "--configs",
                str(configs),
                "--recipes",
                str(recipes),
            ]
        )


@pytest.mark.slow  # about 45 s: a training killed and run again
def test_a_killed_pipeline_leaves_no_stage_running_and_a_rerun_resumes(settings, pipeline_run):
    out, _ = pipeline_run
    configs, recipes = settings
    recovery_config = configs / SLUG / "train_recovery.json"  # the recovery stage runs again, the rest not
    _shrink_json(recovery_config, recovery_config, {"steps": 14, "save_freq": 14})
    # the evaluations add nothing here
    command = _pipeline_command(configs, recipes, out, "--no-chart", "--train-only", methods=["dp"])
    pipeline = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, text=True)
    for line in pipeline.stdout:  # wait until the recovery stage's lerobot-train is running
        if "train_recovery: lerobot-train" in line:
            break
    children_file = Path(f"/proc/{pipeline.pid}/task/{pipeline.pid}/children")
    children: list[int] = []
    while not children and pipeline.poll() is None:  # the command is printed just before it starts
        children = [int(pid) for pid in children_file.read_text().split()]
    assert children, "the stage runs as a child process"
    pipeline.kill()  # SIGKILL: no handler of the pipeline runs
    pipeline.wait()
    while any(_running(pid) for pid in children):  # the kernel delivers the child's death signal
        time.sleep(0.2)
    log = out / SLUG / "logs" / "train_recovery.log"
    assert "End of training" not in log.read_text()  # killed, not finished
    stdout = _run_pipeline(configs, recipes, out, "--train-only", methods=["dp"])
    # the killed stage reruns, the finished ones before it do not
    assert stdout.count("done already") == 3 and "train_recovery: lerobot-train" in stdout
    assert "End of training" in log.read_text()
    step = out / SLUG / "recovery" / "checkpoints" / "last" / "training_state" / "training_step.json"
    assert json.loads(step.read_text())["step"] == 14


def _running(pid: int) -> bool:
    """Whether `pid` is alive and not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ")[1][0] != "Z"
    except (FileNotFoundError, IndexError):
        return False


def test_bad_task_and_missing_settings_are_named(settings, tmp_path):
    configs, recipes = settings
    with pytest.raises(ValueError, match="Unknown task"):
        TaskFiles.locate("PushT-v0", configs, recipes, tmp_path)
    with pytest.raises(FileNotFoundError, match="button_search"):
        TaskFiles.locate("ButtonSearch-lite-v0", configs, recipes, tmp_path)
    with pytest.raises(SystemExit):
        main(["--tasks", TASK, "--methods", "oracle"])


@pytest.mark.slow  # about 100 s; the camera paths are covered stage by stage in tests/policy/test_cameras.py
def test_the_pixel_variant_runs_every_stage_on_cameras(tmp_path):
    """--obs-type pixels_agent_pos: camera demos as video, a camera checkpoint, image-free recovery rows, and
    CCDP evaluated on rendered frames (DP runs the same checkpoint with its recovery off)."""
    slug = f"{SLUG}_pixels"
    configs, recipes = _shrunk_settings(tmp_path / "settings", slug, n_episodes=2)
    out = tmp_path / "out"
    _run_pipeline(configs, recipes, out, "--obs-type", "pixels_agent_pos", "--no-chart", methods=["ccdp"])
    task_out = out / slug

    demos = LeRobotDataset(f"local/{slug}", root=task_out / "demos", video_backend=video_backend())
    assert demos.meta.video_keys == [f"{OBS_IMAGES}.front"]
    recovery = CCDPPolicy.from_pretrained(task_out / "recovery" / CHECKPOINT)
    assert bool(recovery.model.recovery_trained) and list(recovery.config.image_features) == [
        f"{OBS_IMAGES}.front"
    ]
    recovery_meta = LeRobotDataset(f"local/{slug}_recovery", root=task_out / "recovery_data").meta
    assert not recovery_meta.video_keys and f"{OBS_IMAGES}.front" in recovery_meta.stats
    assert len(Episodes.from_eval_info(task_out / "eval" / "ccdp" / "eval_info.json")) == 2
    assert "| DoorOpening-lite-v0 | CCDP |" in (out / "report.md").read_text()


def test_a_config_of_the_other_obs_type_is_refused(settings, tmp_path):
    """State configs filed under the pixel variant's name would train a state policy and report it as
    pixels."""
    configs, recipes = settings
    shutil.copytree(configs / SLUG, tmp_path / f"{SLUG}_pixels")
    shutil.copy(recipes / f"{SLUG}.yaml", tmp_path / f"{SLUG}_pixels.yaml")
    with pytest.raises(ValueError, match="obs_type='state', not 'pixels_agent_pos'"):
        TaskFiles.locate(TASK, tmp_path, tmp_path, tmp_path / "out", "pixels_agent_pos")


# about 80 s; the classifier head trains and samples in CI through tests/recovery/test_preferences.py
@pytest.mark.slow
def test_the_classifier_head_trains_on_the_demos_without_synthesis(tmp_path):
    """A base config naming `recovery_head: classifier` makes the recovery stage learn from the
    demonstrations: no synthesis stage runs, the checkpoint holds a trained classifier, lerobot-eval runs CCDP
    with the sampling settings of methods.json, and the report names that form."""
    configs, recipes = _shrunk_settings(tmp_path / "settings", SLUG, n_episodes=2)
    _shrink_json(
        configs / SLUG / "train_base.json",
        configs / SLUG / "train_base.json",
        {"policy": {"recovery_head": "classifier", "w_z": 1.0}},
    )
    (configs / SLUG / "methods.json").write_text(json.dumps({"ccdp": {"w_z": 2.0}}))
    out = tmp_path / "out"
    stdout = _run_pipeline(configs, recipes, out, "--no-chart", methods=["ccdp"])
    task_out = out / SLUG

    assert not (task_out / "recovery_data").exists()
    assert "synthesize" not in json.loads((task_out / "timings.json").read_text())
    recovery = CCDPPolicy.from_pretrained(task_out / "recovery" / CHECKPOINT)
    assert recovery.config.recovery_head == "classifier" and bool(recovery.model.recovery_trained)
    assert f"--dataset.root={task_out / 'demos'} --output_dir={task_out / 'recovery'}" in stdout
    assert len(Episodes.from_eval_info(task_out / "eval" / "ccdp" / "eval_info.json")) == 2
    assert "--policy.w_z=2.0" in stdout
    report = (out / "report.md").read_text()
    assert "failures by classifier guidance, w_z 2 |" in report


@pytest.mark.slow  # about 3 minutes on 2 busy cores: a pipeline with two heads
def test_the_eps_z_column_beside_a_set_denoiser_trains_from_the_same_base_and_reports_as_its_own(tmp_path):
    """`--methods dp ccdp ccdp_eps_z` on a task whose head is the set denoiser (the Panda tasks' form, with
    a set-denoiser setting and the recipe's siblings): eq. (4)'s eps_z heads get pairs and a recovery stage
    of their own from the same base through the real CLIs, are evaluated on the same seeds, and the report,
    the published run file and the results table name their column."""
    configs, recipes = _shrunk_settings(tmp_path / "settings", SLUG, n_episodes=2)
    train_base = configs / SLUG / "train_base.json"
    _shrink_json(
        train_base, train_base, {"policy": {"recovery_head": "set_denoiser", "stratum_weights": True}}
    )
    recipe = yaml.safe_load((recipes / f"{SLUG}.yaml").read_text())
    recipe["recovery"]["demo_siblings"] = True
    (recipes / f"{SLUG}.yaml").write_text(yaml.safe_dump(recipe))
    out = tmp_path / "out"
    methods = ["dp", "ccdp", "ccdp_eps_z"]
    _run_pipeline(
        configs, recipes, out, "--no-chart", "--publish", str(out / "docs" / "b.md"), methods=methods
    )
    task_out = out / SLUG

    base = CCDPPolicy.from_pretrained(task_out / "base" / CHECKPOINT)
    own = CCDPPolicy.from_pretrained(task_out / "recovery" / CHECKPOINT)
    eps_z = CCDPPolicy.from_pretrained(task_out / "recovery_eps_z" / CHECKPOINT)
    assert own.config.recovery_head == "set_denoiser" and own.config.stratum_weights
    assert eps_z.config.recovery_head == "unet" and not eps_z.config.stratum_weights
    assert bool(eps_z.model.recovery_trained)
    for name, weight in base.model.base.state_dict().items():  # the same base, frozen
        assert torch.equal(weight, eps_z.model.base.state_dict()[name]), name
    pairs = LeRobotDataset(f"local/{SLUG}_recovery_eps_z", root=task_out / "recovery_data_eps_z")
    assert "failure_action" in pairs.features  # eq. (5)'s pairs, not the set denoiser's rows
    made = yaml.safe_load(
        (task_out / "recovery_data_eps_z" / "meta" / "ccdp_recovery_recipe.yaml").read_text()
    )
    assert made["recovery_head"] == "unet" and made["source"]["policy_path"] == str(
        task_out / "base" / CHECKPOINT
    )
    assert len(Episodes.from_eval_info(task_out / "eval" / "ccdp_eps_z" / "eval_info.json")) == 2
    assert {"synthesize_eps_z", "train_recovery_eps_z", "eval_ccdp_eps_z"} <= set(
        json.loads((task_out / "timings.json").read_text())
    )
    report = (out / "report.md").read_text()
    label = "CCDP, eq. (4) eps_z heads"
    assert f"| {TASK} | {label} | 2 |" in report
    forms = report.split("## What ran")[1].split("## Targets")[0]
    assert f"| {TASK}, {label} | {EVAL_SEED}-{EVAL_SEED + 1} | primitive | " in forms
    assert Run.load(out / "docs" / "b.json").labels[TASK] == {
        "dp": "DP",
        "ccdp": "CCDP",
        "ccdp_eps_z": label,
        "oracle": "no-repeat oracle",
    }


def test_the_report_names_where_a_label_free_failure_was_read_and_where_options_end():
    settings = {
        "failure_feature": "final_state",
        "failure_state_dims": [1, 2],
        "failure_state_at": "demonstrated_end",
    }
    assert z_description(settings) == "final_state: state dims [1, 2], a failure's read at demonstrated_end"
    assert z_description({"failure_feature": "primitive"}) == "primitive"
    at_end = {"failure_feature": "primitive", "failure_label_at": "attempt_end"}
    assert z_description(at_end) == "primitive, a failure's label read at attempt_end"
    assert z_description({"failure_feature": "action"}) == "action: the attempt's first chunk"
    dropped = {**settings, "failure_segments": "drops"}
    assert z_description(dropped).endswith("demonstrated_end, demonstrated options end at drops")
    assert z_description({**settings, "z_fourier_octaves": 4}).endswith("demonstrated_end, 4 Fourier octaves")


def test_the_forms_table_names_the_set_denoisers_window_of_guided_steps_and_its_guard():
    assert w_z_window(None) == ""
    assert w_z_window(3) == " on the first 3 steps, 1 after"
    assert w_z_window(None, 4) == "; its guard on the last 4 steps"
    assert w_z_window(3, 2).endswith("1 after; its guard on the last 2 steps")
    assert w_z_window(None, 8, 2.0) == "; its guard on the last 8 steps at weight 2"


@pytest.mark.slow  # three trainings of 20 steps through lerobot-train
def test_throughput_times_the_base_the_head_and_lerobots_diffusion_with_the_same_unet(
    settings, pipeline_run, tmp_path, capsys
):
    from lerobot_ccdp.benchmark import throughput

    out, _ = pipeline_run
    configs, recipes = settings
    throughput.main(
        [
            *("--task", TASK, "--run", str(out), "--configs", str(configs), "--recipes", str(recipes)),
            *("--out", str(tmp_path / "throughput"), "--steps", "20", "--repeats", "2", "--beside"),
        ]
    )
    assert psutil.Process().children() == []  # the busy process beside was stopped with the runs
    rows = [line.split("|")[1:-1] for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    assert [r[0].strip() for r in rows[1:]] == ["diffusion", "ccdp base", "ccdp recovery"]
    assert all(float(r[1]) > 0 and r[2].strip().endswith("%") for r in rows[1:])
    assert rows[1][3].strip() == "1.00x"
    diffusion = json.loads(
        (tmp_path / "throughput/train/diffusion/checkpoints/last/pretrained_model/config.json").read_text()
    )
    base = json.loads((out / SLUG / "base" / CHECKPOINT / "config.json").read_text())
    assert diffusion["type"] == "diffusion"
    assert all(diffusion[k] == base[k] for k in throughput.SHARED_FIELDS)
