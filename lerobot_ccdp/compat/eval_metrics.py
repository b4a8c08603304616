"""Per-episode task metrics in lerobot-eval's eval_info.json: attempts, failures, repeated failures,
preference.

LeRobot's eval loop keeps only the reward and `is_success` of each episode, but the CCDP comparison (DESIGN
section 8) needs the rest of the env's final `info`. This module wraps `lerobot_eval.eval_one` (installed on
plugin import, so `lerobot-eval` and lerobot-train's periodic eval both use it): it watches the vector env,
keeps each episode's final info, and adds one list per key of `EPISODE_INFO_KEYS` to the task's metrics,
which lerobot-eval writes to eval_info.json under `per_task[i]["metrics"]`, in the same episode order as
`successes`. Envs that report none of these keys are left alone.

It also saves LeRobot from rendering videos of envs that cannot render (`--env.render_mode=null`): LeRobot
0.4 always renders 10 episodes, which on a CPU (software OpenGL, ~50 ms a frame) costs more than the rollouts.
"""

from __future__ import annotations

import functools
import logging
import sys
from typing import Any

import gymnasium as gym
import numpy as np

logger = logging.getLogger(__name__)

EPISODE_INFO_KEYS = (
    "attempts",
    "failures",
    "repeated_failures",
    "attempts_after_failure",
    "preference_matched",
)


def _row(info: dict[str, Any], key: str, i: int) -> Any | None:
    """Value of `key` for sub-env `i` in a vector env's info dict (None where that env did not report it)."""
    if key not in info or not info.get(f"_{key}", np.ones(i + 1, dtype=bool))[i]:
        return None
    value = info[key][i]
    return value.item() if isinstance(value, np.generic) else value


class EpisodeInfoRecorder:
    """Keeps the final `EPISODE_INFO_KEYS` of every episode a vector env runs, in lerobot-eval's order.

    lerobot-eval resets the vector env once per batch of episodes and steps it until every sub-env is done;
    with LeRobot's SAME_STEP autoreset, an episode's last info arrives under `final_info`. Until a sub-env is
    done, its latest info stands in (rollouts cut at the step limit).
    """

    def __init__(self, env: gym.vector.VectorEnv):
        self.env = env
        self.episodes: list[dict[str, Any]] = []
        self._batch: list[dict[str, Any]] = []
        self._done = np.zeros(env.num_envs, dtype=bool)
        self._step, self._reset = env.step, env.reset
        env.step, env.reset = self.step, self.reset

    def reset(self, *args, **kwargs):
        self._flush()
        observation, info = self._reset(*args, **kwargs)
        self._batch = [{} for _ in range(self.env.num_envs)]
        self._done[:] = False
        self._update(info, ~self._done)
        return observation, info

    def step(self, action):
        observation, reward, terminated, truncated, info = self._step(action)
        ended = (np.asarray(terminated) | np.asarray(truncated)) & ~self._done
        self._update(info, ~self._done & ~ended)
        self._update(info.get("final_info", info), ended)
        self._done |= ended
        return observation, reward, terminated, truncated, info

    def detach(self) -> None:
        """Give the env its own step/reset back and close the last batch."""
        self._flush()
        self.env.step, self.env.reset = self._step, self._reset

    def metrics(self, n_episodes: int) -> dict[str, list]:
        """One list per reported key over the first `n_episodes` episodes (lerobot-eval drops the rest)."""
        episodes = self.episodes[:n_episodes]
        keys = [k for k in EPISODE_INFO_KEYS if episodes and all(k in e for e in episodes)]
        return {key: [e[key] for e in episodes] for key in keys}

    def _update(self, info: dict[str, Any], rows: np.ndarray) -> None:
        for i in np.flatnonzero(rows):
            for key in EPISODE_INFO_KEYS:
                value = _row(info, key, i)
                if value is not None:
                    self._batch[i][key] = value

    def _flush(self) -> None:
        self.episodes.extend(self._batch)
        self._batch = []


def summary(metrics: dict[str, list]) -> str:
    """One log line: success rate, mean attempts of successes, repeated-failure rate, preference adherence."""
    success = np.asarray(metrics["successes"], dtype=bool)
    attempts = np.asarray(metrics["attempts"], dtype=float)
    repeated = np.asarray(metrics["repeated_failures"], dtype=float)
    preference = np.asarray(metrics["preference_matched"], dtype=bool)
    mean_attempts = attempts[success].mean() if success.any() else float("nan")
    adherence = preference[success].mean() if success.any() else float("nan")
    return (
        f"success {success.mean():.3f}, attempts (successes) {mean_attempts:.2f}, repeated-failure rate "
        f"{repeated.sum() / max(attempts.sum(), 1):.3f}, preference adherence (successes) {adherence:.3f}"
    )


def is_ccdp_env(env: gym.vector.VectorEnv) -> bool:
    """Whether a vector env runs this package's tasks (other envs are left to LeRobot untouched)."""
    from lerobot_ccdp.envs.tasks import GYM_NAMESPACE

    try:
        specs = env.get_attr("spec")
    except AttributeError:
        return False
    return bool(specs) and all(spec is not None and spec.id.startswith(f"{GYM_NAMESPACE}/") for spec in specs)


def install_episode_metrics(import_eval: bool = True) -> None:
    """Wrap lerobot_eval.eval_one once (run_one looks it up at call time).

    On plugin import (`import_eval=False`) only where lerobot_eval is already loaded (the lerobot-eval and
    lerobot-train CLIs import it before plugins), so other CLIs never load it; a `ccdp` env config installs it
    too, for evaluations started from Python."""
    if not import_eval and "lerobot.scripts.lerobot_eval" not in sys.modules:
        return
    import lerobot.scripts.lerobot_eval as lerobot_eval

    original = lerobot_eval.eval_one
    if getattr(original, "_ccdp_episode_metrics", False):
        return

    @functools.wraps(original)
    def eval_one_with_episode_metrics(env: gym.vector.VectorEnv, **kwargs):
        if not is_ccdp_env(env):
            return original(env, **kwargs)
        if getattr(env, "render_mode", None) is None:
            kwargs["max_episodes_rendered"] = 0
        recorder = EpisodeInfoRecorder(env)
        try:
            metrics = original(env, **kwargs)
        finally:
            recorder.detach()
        extra = recorder.metrics(len(metrics["successes"]))
        metrics.update(extra)
        if len(extra) == len(EPISODE_INFO_KEYS):
            logger.info("Episode metrics: %s", summary(metrics))
        return metrics

    eval_one_with_episode_metrics._ccdp_episode_metrics = True
    lerobot_eval.eval_one = eval_one_with_episode_metrics
