"""The CCDP and DP* each task's benchmark evaluates, and that the policy's defaults are them.

BENCHMARKED holds, per settings folder, the form the pipeline evaluates: the one configuration (issue 114) for
the set-denoiser folders, chosen on the development seeds 1000-1099 (docs/benchmarks.md, "The one
configuration"): the window (`w_z` 5 on the 3 noisiest steps) and the guard on the last 4 at weight 8, the
same for every Panda folder (tests/benchmark/test_one_configuration.py). The test rounds before it evaluated
the forms docs/results.md names per round (no guard on the door, buttons, box and packing; `w_z` 1 and the
guard on 8 steps on the labelled Bartender, a failure's label at the attempt's end there; `w_z` 1, `delta_z`
0.05 and z at the attempt's end on the label-free Bartender; z in no Fourier octaves on the label-free door,
box and packing). Each test builds the evaluated config as lerobot-eval does: the checkpoint's config.json
(train_base.json's policy on the policy's defaults) with the command's --policy.* flags on top
(`PreTrainedConfig.from_pretrained(path, cli_overrides=...)`).
"""

import json
import re
from pathlib import Path

import pytest
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType
from lerobot.envs.utils import env_to_policy_features

from lerobot_ccdp.benchmark.pipeline import LABEL_FREE as LABEL_FREE_SUFFIX
from lerobot_ccdp.benchmark.pipeline import OBS_VARIANTS, RECOVERY_MODE, TaskFiles, task_slug
from lerobot_ccdp.envs import TASKS, CCDPEnvConfig
from lerobot_ccdp.policy.composition import CompositionWeights
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig, z_fourier_octaves_of

REPO = Path(__file__).resolve().parents[2]
CONFIGS, RECIPES = REPO / "configs", REPO / "datasets_recipes"
STEPS = 10  # the reverse steps of every shipped config (num_inference_steps)
EARLY_5 = (5,) * 3 + (1,) * 7  # w_z 5 on the 3 noisiest steps, 1 after
EVERY = {w: (w,) * STEPS for w in (1, 3)}
# The set denoiser's guard: (failure_guard_steps, failure_guard_weight); the unet heads have none.
GUARD, NO_GUARD = (4, 8.0), (0, 1.0)


def _setting(
    w_z, guard=GUARD, delta_z=0.1, state_at="demonstrated_end", label_at="latest_chunk", octaves=0, dp_star=32
):
    return {
        "ccdp": (w_z, guard, delta_z, state_at, label_at, octaves),
        "dp_star": (dp_star, 4, delta_z, state_at, label_at, octaves),
    }


PANDA = ("door_opening", "button_search", "object_manipulation", "object_packing", "bartender")
LABELLED = {slug: _setting(EARLY_5) for slug in PANDA}
LABEL_FREE = {f"{slug}_label_free": _setting(EARLY_5, octaves=4) for slug in PANDA}
LITE = {f"{slug}_lite": _setting(EVERY[3], guard=NO_GUARD) for slug in PANDA}
PIXELS = {slug: _setting(EVERY[3], guard=NO_GUARD, dp_star=16) for slug in ("door_opening", "button_search")}
BENCHMARKED = {
    **LABELLED,
    **LABEL_FREE,
    **LITE,
    **{f"{slug}_pixels": s for slug, s in PIXELS.items()},
    **{f"{slug}_lite_pixels": s for slug, s in PIXELS.items()},
}
# The Evaluate section's command names a checkpoint of configs/door_opening.
README_TASK = "door_opening"


def _settings_folders() -> dict[str, tuple[str, str, bool]]:
    """Every settings folder the pipeline can run: slug -> (task, obs_type, label_free)."""
    folders = {}
    for task in TASKS:
        for obs_type in OBS_VARIANTS:
            for label_free in (False, True):
                slug = task_slug(task) + OBS_VARIANTS[obs_type] + (LABEL_FREE_SUFFIX if label_free else "")
                if (CONFIGS / slug / "eval.json").is_file():
                    folders[slug] = (task, obs_type, label_free)
    return folders


def _evaluated(files: TaskFiles, flags: list[str], tmp_path: Path) -> CCDPConfig:
    """The config lerobot-eval evaluates: the checkpoint's config.json, with the recovery head lerobot-train
    names there for the task's inputs, and the command's --policy.* flags."""
    policy = {k: v for k, v in json.loads(files.train_base.read_text())["policy"].items() if k != "type"}
    policy["recovery_head"] = files.recovery_head()
    tmp_path.mkdir(exist_ok=True)
    CCDPConfig(**policy, device="cpu")._save_pretrained(tmp_path)
    overrides = [
        f"--{f.removeprefix('--policy.')}"
        for f in flags
        if f.startswith("--policy.") and not f.startswith("--policy.path=")
    ]
    return PreTrainedConfig.from_pretrained(tmp_path, cli_overrides=overrides)


def _effective(config: CCDPConfig, method: str) -> tuple:
    """What a mode samples with: CCDP's w_z at each reverse step, its guard, and the failure lookup (with the
    Fourier octaves the head reads a z in); DP*'s candidates and rounds, and the same lookup."""
    lookup = (config.delta_z, config.failure_state_at, config.failure_label_at, z_fourier_octaves_of(config))
    if method == "dp_star":
        return (config.dp_star_candidates, config.dp_star_rounds, *lookup)
    if config.recovery_head == "set_denoiser":
        weights = CompositionWeights(w_z=config.w_z, w_z_steps=config.w_z_steps)
        schedule = tuple(weights.at_step(i).w_z for i in range(config.num_inference_steps))
    else:  # the unet and classifier heads weigh every step alike
        schedule = (config.w_z,) * config.num_inference_steps
    guard = (config.failure_guard_steps, config.failure_guard_weight)
    return (schedule, guard if config.recovery_head == "set_denoiser" else NO_GUARD, *lookup)


def test_every_settings_folder_has_its_benchmarked_form():
    assert set(_settings_folders()) == set(BENCHMARKED)


@pytest.mark.parametrize("slug", sorted(BENCHMARKED))
@pytest.mark.parametrize("method", ["ccdp", "dp_star"])
def test_the_pipeline_evaluates_what_the_benchmark_did(slug, method, tmp_path):
    """The pipeline's lerobot-eval command for each mode samples as the published rounds did, with the
    defaults now the benchmark's and the settings files holding only what departs from them."""
    task, obs_type, label_free = _settings_folders()[slug]
    files = TaskFiles.locate(task, CONFIGS, RECIPES, tmp_path / "out", obs_type, label_free)
    assert files.out.name == slug
    command = files.eval_command(Path("ckpt"), method, 0, tmp_path / "eval", files.method_flags(method))
    config = _evaluated(files, command, tmp_path / "ckpt")
    assert config.recovery_mode == RECOVERY_MODE[method] and config.row_noise_streams
    assert _effective(config, method) == BENCHMARKED[slug][method]


def _task_of(slug: str) -> str:
    return _settings_folders()[slug][0]


def _readme_evaluate_flags() -> list[str]:
    readme = (REPO / "README.md").read_text()
    section = readme.split("## Evaluate", 1)[1].split("\n## ", 1)[0]
    command = re.search(r"```bash\n(.*?)```", section, flags=re.DOTALL).group(1).replace("\\\n", " ")
    return re.findall(r"--policy\.\S+", command.split("#", 1)[0])


@pytest.mark.parametrize("method", ["ccdp", "dp_star"])
def test_the_readmes_evaluate_command_evaluates_the_benchmarked_methods(method, tmp_path):
    """README's Evaluate, with `--policy.recovery_mode` set to the mode, on a checkpoint trained with the
    task's configs: the CCDP and DP* of the results table, common random numbers on."""
    flags = [f for f in _readme_evaluate_flags() if not f.startswith("--policy.recovery_mode")]
    files = TaskFiles.locate(_task_of(README_TASK), CONFIGS, RECIPES, tmp_path / "out")
    config = _evaluated(files, [*flags, f"--policy.recovery_mode={method}"], tmp_path / "ckpt")
    assert config.row_noise_streams
    assert _effective(config, method) == BENCHMARKED[README_TASK][method]


def test_the_policys_defaults_are_the_benchmarks():
    """What the shipped set-denoiser configs evaluate is CCDPConfig's own default, its head included: the one
    it names for the door's state inputs, as lerobot-train's make_policy gives them. The label-free door is
    the folder whose z is the default's (`final_state`, read at the demonstrated end, in 4 octaves)."""
    features = env_to_policy_features(CCDPEnvConfig(task=_task_of(README_TASK)))
    config = CCDPConfig(
        input_features={k: f for k, f in features.items() if f.type is not FeatureType.ACTION},
        output_features={k: f for k, f in features.items() if f.type is FeatureType.ACTION},
        device="cpu",
    )
    config.validate_features()
    assert config.recovery_head == "set_denoiser"
    assert _effective(config, "ccdp") == BENCHMARKED["door_opening_label_free"]["ccdp"]
    assert _effective(config, "dp_star") == BENCHMARKED["door_opening_label_free"]["dp_star"]
    assert config.row_noise_streams
