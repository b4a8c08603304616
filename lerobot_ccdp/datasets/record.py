"""`lerobot-ccdp-record`: record scripted-expert demonstrations of a CCDP task as a local LeRobot dataset.

The dataset holds what the env observes: `observation.state` and `observation.environment_state` (obs_type
`state`), or `observation.state` and one `observation.images.<camera>` video per camera (obs_type
`pixels_agent_pos`, set in the recipe's `env_kwargs`), then `action`, plus two per-frame labels: `primitive`
(the option the expert executes in that frame) and `hidden_param` (the episode's hidden parameter, for
analysis; no policy input reads it). Only successful episodes are kept. It is written to a temporary folder
next to `--dataset.root` and renamed into place when complete, so an interrupted run leaves nothing
half-written there; its ownership marker lets `--overwrite` replace it later.

    lerobot-ccdp-record --config_path=datasets_recipes/door_opening.yaml \
        --dataset.repo_id=local/door_opening --dataset.root=data/door_opening [--record.n_episodes=20]
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import yaml
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_IMAGES, OBS_STATE
from tqdm import tqdm

from lerobot_ccdp.compat.episode_writes import image_free_episodes
from lerobot_ccdp.datasets.configs import RecordConfig, parse_cli
from lerobot_ccdp.datasets.recipe_file import RecordRecipe
from lerobot_ccdp.datasets.staging import check_output_root, staged_dataset_root
from lerobot_ccdp.envs.base import ACTION_NAMES, AGENT_POS_NAMES, CCDPTaskEnv
from lerobot_ccdp.envs.scripted import Episode, Expert, run_episode
from lerobot_ccdp.envs.tasks import gym_id

logger = logging.getLogger(__name__)

PRIMITIVE = "primitive"
HIDDEN_PARAM = "hidden_param"
RECIPE_COPY = "meta/ccdp_record_recipe.yaml"


class RecordingRefused(RuntimeError):
    """Env settings the env refuses, or an expert that failed more episodes than were asked for: the message
    names the cause and its fix, and the command prints it as its one line."""


def dataset_features(env: CCDPTaskEnv) -> dict[str, dict]:
    """LeRobot feature spec of a task's demo dataset, from what the env observes (cameras are stored as
    videos)."""
    features = {
        OBS_STATE: {"dtype": "float32", "shape": (len(AGENT_POS_NAMES),), "names": list(AGENT_POS_NAMES)}
    }
    spaces = env.observation_space.spaces
    if "environment_state" in spaces:
        names = list(env.env_state_names)
        features[OBS_ENV_STATE] = {"dtype": "float32", "shape": (len(names),), "names": names}
    for camera, space in spaces.get("pixels", {}).items():
        features[f"{OBS_IMAGES}.{camera}"] = {
            "dtype": "video",
            "shape": space.shape,
            "names": ["height", "width", "channels"],
        }
    return {
        **features,
        ACTION: {"dtype": "float32", "shape": (len(ACTION_NAMES),), "names": list(ACTION_NAMES)},
        PRIMITIVE: {"dtype": "int64", "shape": (1,), "names": None},
        HIDDEN_PARAM: {"dtype": "float32", "shape": (1,), "names": None},
    }


def _observation_frame(observation: dict) -> dict[str, np.ndarray]:
    """The dataset columns of one env observation."""
    frame = {OBS_STATE: observation["agent_pos"]}
    if "environment_state" in observation:
        frame[OBS_ENV_STATE] = observation["environment_state"]
    for camera, image in observation.get("pixels", {}).items():
        frame[f"{OBS_IMAGES}.{camera}"] = image
    return frame


def _add_episode(dataset: LeRobotDataset, episode: Episode, description: str) -> None:
    hidden = np.array([episode.hidden_param], dtype=np.float32)
    for observation, action, option in zip(
        episode.observations, episode.actions, episode.options, strict=True
    ):
        dataset.add_frame(
            {
                **_observation_frame(observation),
                ACTION: np.asarray(action, dtype=np.float32),
                PRIMITIVE: np.array([option], dtype=np.int64),
                HIDDEN_PARAM: hidden,
                "task": description,
            }
        )
    dataset.save_episode()


def record_dataset(
    recipe: RecordRecipe, repo_id: str, root: str | Path, overwrite: bool = False, progress: bool = True
) -> Path:
    """Record `recipe.n_episodes` expert successes into a LeRobot dataset at `root`; return `root`."""
    try:
        env = gym.make(gym_id(recipe.task), **_env_kwargs(recipe))
    except ValueError as error:  # a setting out of range (the recipe checked the names and types)
        raise RecordingRefused(f"record.env_kwargs: {error}") from error
    try:
        with staged_dataset_root(root, overwrite) as staging, image_free_episodes():
            discarded = _record_into(staging, recipe, repo_id, env, progress)
    finally:
        env.close()
    logger.info(
        "Recorded %d episodes (%d discarded) of %s to %s", recipe.n_episodes, discarded, recipe.task, root
    )
    return root


def _record_into(path: Path, recipe: RecordRecipe, repo_id: str, env: gym.Env, progress: bool) -> int:
    """Record the recipe's episodes into a new dataset at `path`; return how many expert failures were
    discarded."""
    description = recipe.task_description or env.unwrapped.task_description
    features = dataset_features(env.unwrapped)
    dataset = LeRobotDataset.create(
        repo_id=repo_id,
        fps=recipe.fps,
        features=features,
        root=path,
        robot_type="ccdp_cartesian_gripper",
        use_videos=any(spec["dtype"] == "video" for spec in features.values()),
    )
    try:
        expert = Expert(env)
        seed, discarded, timed_out = recipe.seed, 0, 0
        for _ in tqdm(range(recipe.n_episodes), desc=f"Recording {recipe.task}", disable=not progress):
            while True:
                episode = run_episode(env, expert, seed=seed)
                seed += 1
                if episode.success:
                    break
                discarded += 1
                timed_out += len(episode.actions) >= env.spec.max_episode_steps
                logger.warning(
                    "Expert failed on seed %d (hidden_param=%d); episode discarded",
                    seed - 1,
                    episode.hidden_param,
                )
                if discarded > recipe.n_episodes:
                    raise RecordingRefused(
                        f"The {recipe.task} expert failed {discarded} times; giving up. "
                        + _why_the_expert_failed(recipe, env, timed_out == discarded)
                    )
            _add_episode(dataset, episode, description)
    finally:
        # close its writers now, or their destructors write into the deleted staging folder
        dataset.finalize()
    (path / RECIPE_COPY).write_text(yaml.safe_dump({"record": _as_dict(recipe)}, sort_keys=False))
    return discarded


def _why_the_expert_failed(recipe: RecordRecipe, env: gym.Env, all_timed_out: bool) -> str:
    """The likely cause of the expert's failures, and its fix: a step limit too short for it, or settings."""
    own = gym.spec(gym_id(recipe.task)).max_episode_steps
    if not all_timed_out:
        return (
            "The scripted expert rarely fails the task as registered; check what the recipe changes "
            f"(record.env_kwargs={recipe.env_kwargs}, record.seed={recipe.seed})."
        )
    if recipe.max_episode_steps is not None and recipe.max_episode_steps < own:
        return (
            f"Every failed episode ran to its step limit of {recipe.max_episode_steps} steps "
            "(record.max_episode_steps), too few for the expert: raise --record.max_episode_steps (the "
            f"task's own limit: {own}) or leave it unset."
        )
    return (
        f"Every failed episode ran to its step limit of {env.spec.max_episode_steps} steps; raise "
        "--record.max_episode_steps, or check what record.env_kwargs changes."
    )


def _env_kwargs(recipe: RecordRecipe) -> dict:
    kwargs = dict(recipe.env_kwargs)
    if recipe.max_episode_steps is not None:
        kwargs["max_episode_steps"] = recipe.max_episode_steps
    return kwargs


def _as_dict(recipe: RecordRecipe) -> dict:
    return {k: v for k, v in vars(recipe).items() if v is not None and v != {}}


def main(args: list[str] | None = None) -> None:
    """`lerobot-ccdp-record --config_path=<recipe yaml> --dataset.repo_id=... --dataset.root=...` (see
    --help)."""
    cfg = parse_cli(RecordConfig, args)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    start = time.perf_counter()
    # A root it cannot use (checked before the env is made) and an expert that gives up are named in one
    # line, as a recipe error is, and so are env settings the env refuses; a failure while writing keeps its
    # traceback.
    try:
        check_output_root(cfg.dataset.root, cfg.overwrite)
    except (OSError, ValueError) as error:
        raise SystemExit(f"{RecordConfig.command}: error: {error}") from None
    try:
        record_dataset(cfg.record, cfg.dataset.repo_id, cfg.dataset.root, overwrite=cfg.overwrite)
    except RecordingRefused as error:
        raise SystemExit(f"{RecordConfig.command}: error: {error}") from None
    logger.info("Done in %.1f s", time.perf_counter() - start)


if __name__ == "__main__":
    main()
