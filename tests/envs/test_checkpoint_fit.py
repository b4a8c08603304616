"""lerobot-eval refuses a checkpoint that does not fit the env before the first step, naming every feature.

Before, a DoorOpening-lite checkpoint evaluated on ButtonSearch-lite built the policy, started the rollout and
died in LeRobot's normaliser ("size 8 vs 3"). The runs go through lerobot-eval's own entry point, in-process.
"""

from pathlib import Path

import pytest
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.scripts import lerobot_eval

from lerobot_ccdp.compat.env_fit import refuse_unfit_checkpoint
from lerobot_ccdp.envs import CCDPEnvConfig
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

from fixtures.lite_eval import run_lerobot_eval


def _lerobot_eval(checkpoint: Path, task: str, out: Path, monkeypatch, *extra: str) -> None:
    run_lerobot_eval(
        monkeypatch,
        checkpoint,
        task,
        "--env.episode_length=2",
        "--eval.n_episodes=1",
        "--eval.batch_size=1",
        f"--output_dir={out}",
        *extra,
    )


def test_a_checkpoint_of_another_task_is_refused_before_the_rollout(
    door_lite_checkpoint, tmp_path, monkeypatch
):
    rollouts, rollout = [], lerobot_eval.rollout

    def counted_rollout(*args, **kwargs):
        rollouts.append(args)
        return rollout(*args, **kwargs)

    monkeypatch.setattr(lerobot_eval, "rollout", counted_rollout)
    with pytest.raises(ValueError) as refused:
        _lerobot_eval(door_lite_checkpoint, "ButtonSearch-lite-v0", tmp_path / "eval", monkeypatch)
    assert str(refused.value) == (
        f"The checkpoint {door_lite_checkpoint} does not fit --env.task=ButtonSearch-lite-v0 "
        "(--env.obs_type=state): observation.environment_state has shape (3,) in the checkpoint and (8,) in "
        "the env. The checkpoint fits --env.task=DoorOpening-v0 or DoorOpening-lite-v0: evaluate it there, "
        "or use a checkpoint trained on ButtonSearch-lite-v0."
    )
    assert not rollouts


def test_the_checkpoints_own_task_evaluates(door_lite_checkpoint, tmp_path, monkeypatch):
    _lerobot_eval(door_lite_checkpoint, "DoorOpening-lite-v0", tmp_path / "eval", monkeypatch)
    assert (tmp_path / "eval" / "eval_info.json").is_file()


def test_every_feature_that_differs_is_named_cameras_and_action_too():
    """A camera checkpoint with a 2-D action on the state env: the missing camera and the action."""
    config = CCDPConfig(
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (4,)),
            "observation.images.front": PolicyFeature(FeatureType.VISUAL, (3, 48, 48)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
        vision_backbone_stages=3,
    )
    with pytest.raises(ValueError) as refused:
        refuse_unfit_checkpoint(config, CCDPEnvConfig(task="DoorOpening-lite-v0"))
    assert str(refused.value) == (
        "The policy does not fit --env.task=DoorOpening-lite-v0 (--env.obs_type=state): "
        "observation.images.front (shape (3, 48, 48) in the checkpoint) is missing from the env; action has "
        "shape (2,) in the checkpoint and (4,) in the env. No ccdp task with these env settings fits it: use "
        "a checkpoint trained on DoorOpening-lite-v0, with the same --env.obs_type and cameras."
    )


def test_a_renamed_camera_fits():
    """`--rename_map` maps the env's keys to the policy's, as LeRobot's preprocessor will."""
    config = CCDPConfig(
        input_features={
            "observation.state": PolicyFeature(FeatureType.STATE, (4,)),
            "observation.images.wrist": PolicyFeature(FeatureType.VISUAL, (3, 48, 48)),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, (4,))},
        vision_backbone_stages=3,
    )
    env = CCDPEnvConfig(
        task="DoorOpening-lite-v0", obs_type="pixels_agent_pos", observation_width=48, observation_height=48
    )
    refuse_unfit_checkpoint(config, env, {"observation.images.front": "observation.images.wrist"})
    with pytest.raises(
        ValueError, match=r"observation.images.wrist \(shape \(3, 48, 48\) in the checkpoint\)"
    ):
        refuse_unfit_checkpoint(config, env)


@pytest.mark.parametrize("seed", [-1, 2**32])
def test_a_seed_numpy_cannot_take_is_named_before_the_env_is_made(
    door_lite_checkpoint, tmp_path, monkeypatch, seed
):
    """Before, numpy's "Seed must be between 0 and 2**32 - 1", 130 lines into a traceback, no flag named."""
    monkeypatch.setattr(lerobot_eval, "make_env", lambda *args, **kwargs: pytest.fail("an env was made"))
    with pytest.raises(
        ValueError, match=rf"--seed={seed}: lerobot-eval seeds numpy with it, which takes 0 to "
    ):
        _lerobot_eval(
            door_lite_checkpoint, "DoorOpening-lite-v0", tmp_path / "eval", monkeypatch, f"--seed={seed}"
        )


def test_a_batch_of_no_envs_is_named_by_its_flag(door_lite_checkpoint, tmp_path, monkeypatch):
    """Before, LeRobot's "`n_envs` must be at least 1", naming no flag."""
    with pytest.raises(
        ValueError, match=r"--eval.batch_size=0: lerobot-eval runs that many envs side by side"
    ):
        _lerobot_eval(
            door_lite_checkpoint, "DoorOpening-lite-v0", tmp_path / "eval", monkeypatch, "--eval.batch_size=0"
        )
