"""The `ccdp` EnvConfig with LeRobot's own env factory, lerobot-train and lerobot-eval."""

import json

import numpy as np
import pytest
from lerobot.envs.configs import EnvConfig
from lerobot.envs.factory import make_env
from lerobot.envs.utils import env_to_policy_features, preprocess_observation

from lerobot_ccdp.datasets.recipe_file import RecordRecipe
from lerobot_ccdp.datasets.record import record_dataset
from lerobot_ccdp.envs import TASKS, CCDPEnvConfig
from lerobot_ccdp.envs.scripted import Expert

from env_helpers import run_cli


def test_env_type_is_registered_with_lerobot():
    assert EnvConfig.get_choice_class("ccdp") is CCDPEnvConfig
    cfg = CCDPEnvConfig(task="Bartender-lite-v0")
    assert cfg.type == "ccdp" and cfg.gym_id == "lerobot_ccdp/Bartender-lite-v0" and cfg.fps == 10
    assert cfg.episode_length == TASKS["Bartender-lite-v0"].default_episode_steps
    assert cfg.features_map == {
        "action": "action",
        "agent_pos": "observation.state",
        "environment_state": "observation.environment_state",
    }
    assert "failure" not in cfg.features
    assert {k: f.shape for k, f in env_to_policy_features(cfg).items()} == {
        "action": (4,),
        "observation.state": (4,),
        "observation.environment_state": (12,),
    }


def test_bad_env_config_is_named():
    with pytest.raises(ValueError, match="known tasks"):
        CCDPEnvConfig(task="PushT-v0")
    with pytest.raises(ValueError, match="fixed 10 fps"):
        CCDPEnvConfig(task="DoorOpening-lite-v0", fps=30)


@pytest.mark.parametrize("task", list(TASKS))
def test_make_env_vector_env_reports_success_like_lerobot_eval_reads_it(task):
    cfg = CCDPEnvConfig(task=task, episode_length=120)
    vec = make_env(cfg, n_envs=1)["ccdp"][0]
    assert vec.call("_max_episode_steps")[0] == 120
    obs, info = vec.reset(seed=[0])
    batch = preprocess_observation(obs)
    assert batch["observation.state"].shape == (1, 4)
    assert batch["observation.environment_state"].shape == (1, len(TASKS[task].env_state_names))
    expert = Expert(vec.envs[0])
    for _ in range(120):
        action = expert.act({k: v[0] for k, v in obs.items()}, {"option": info["option"][0]})
        obs, _, terminated, truncated, info = vec.step(action[None])
        if terminated[0] or truncated[0]:
            break
    assert terminated[0] and bool(info["final_info"]["is_success"][0])
    assert info["final_info"]["preference_matched"][0]
    vec.close()


def _train_and_eval(task: str, tmp_path):
    """Record a few demos, train diffusion a few steps with lerobot's periodic eval on, then lerobot-eval."""
    root = tmp_path / "demos"
    record_dataset(RecordRecipe(task=task, n_episodes=4, seed=0), "local/smoke", root, progress=False)
    out = tmp_path / "train"
    common = [
        "--policy.device=cpu",
        "--policy.num_inference_steps=4",
        "--env.type=ccdp",
        f"--env.task={task}",
        "--env.episode_length=10",
        "--eval.n_episodes=1",
        "--eval.batch_size=1",
    ]
    run_cli(
        "lerobot-train",
        "--policy.type=diffusion",
        "--dataset.repo_id=local/smoke",
        f"--dataset.root={root}",
        f"--output_dir={out}",
        "--steps=2",
        "--batch_size=4",
        "--policy.push_to_hub=false",
        "--num_workers=0",
        "--wandb.enable=false",
        "--save_freq=2",
        "--eval_freq=2",
        "--policy.down_dims=[32,64,128]",
        *common,
    )
    assert list((out / "eval").glob("videos_step_000002/ccdp_0/*.mp4"))  # periodic eval ran on the env
    checkpoint = out / "checkpoints" / "last" / "pretrained_model"
    run_cli("lerobot-eval", f"--policy.path={checkpoint}", f"--output_dir={tmp_path / 'eval'}", *common)
    info = json.loads((tmp_path / "eval" / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1
    assert np.isfinite(info["overall"]["avg_sum_reward"])


@pytest.mark.slow  # about 50 s; ccdp's own lerobot-eval runs in tests/benchmark/test_pipeline.py
def test_lerobot_train_diffusion_and_eval_door_opening(tmp_path):
    _train_and_eval("DoorOpening-lite-v0", tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("task", [t for t in TASKS if t != "DoorOpening-lite-v0"])
def test_lerobot_train_diffusion_and_eval(task, tmp_path):
    _train_and_eval(task, tmp_path)
