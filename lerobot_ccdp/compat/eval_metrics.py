"""What lerobot-eval reports per mode: per-episode task metrics in eval_info.json (attempts, failures,
repeated failures, preference), the results table's metrics on the console, and a job name for the mode.

LeRobot's eval loop keeps only the reward and `is_success` of each episode, but the CCDP comparison (DESIGN
section 8) needs the rest of the env's final `info`. This module wraps `lerobot_eval.eval_one` (installed on
plugin import, so `lerobot-eval` and lerobot-train's periodic eval both use it): it watches the vector env,
keeps each episode's final info, and adds one list per key of `EPISODE_INFO_KEYS` to the task's metrics,
which lerobot-eval writes to eval_info.json under `per_task[i]["metrics"]`, in the same episode order as
`successes`. It then logs the run's row of the results table (`lerobot_ccdp.benchmark.comparison`), named for
the policy's `recovery_mode`. Envs that report none of these keys are left alone.

It also saves LeRobot from rendering videos of envs that cannot render (`--env.render_mode=null`): LeRobot
0.4 always renders 10 episodes, which on a CPU (software OpenGL, ~50 ms a frame) costs more than the rollouts.

Without `--job_name`, LeRobot names every evaluation `<env>_<policy>` (`ccdp_ccdp`), so the three modes'
output folders differ only by their time; `install_mode_job_name` appends the mode (`ccdp_ccdp_dp_star`).
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


def summary(metrics: dict[str, list], mode: str, task: str) -> str:
    """The run's row of the results table, one metric a line under the table's labels, with the counts behind
    the ratios: the console then says what `comparison.MethodMetrics` (and so the report) will say of this
    eval_info.json, e.g. repeats per attempt after a failure, not the per-attempt rate alone."""
    from lerobot_ccdp.benchmark.comparison import METHOD_LABELS, METRIC_LABELS, MethodMetrics
    from lerobot_ccdp.benchmark.episodes import Episodes

    episodes = Episodes.from_infos(
        [
            {"is_success": success, **{key: metrics[key][i] for key in EPISODE_INFO_KEYS}}
            for i, success in enumerate(metrics["successes"])
        ]
    )
    row = MethodMetrics.of(episodes)
    width = max(map(len, METRIC_LABELS.values()))
    lines = [
        f"Mode {mode} ({METHOD_LABELS.get(mode, mode)}) on {task}, {len(episodes)} episodes, as the results "
        "table computes them (docs/evaluation.md):",
        *(f"  {label:<{width}}  {getattr(row, name)}" for name, label in METRIC_LABELS.items()),
        f"  attempts {int(episodes.attempts.sum())}, failures {int(episodes.failures.sum())}, "
        f"attempts after a failure {int(episodes.attempts_after_failure.sum())}, "
        f"repeated failures {int(episodes.repeated_failures.sum())}",
    ]
    return "\n".join(lines)


def mode_of(policy_config: Any) -> str:
    """What a run is named for: a ccdp policy's `recovery_mode` (ccdp, dp or dp_star), another's type."""
    return getattr(policy_config, "recovery_mode", None) or policy_config.type


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
            from lerobot_ccdp.envs.tasks import GYM_NAMESPACE

            task = env.get_attr("spec")[0].id.removeprefix(f"{GYM_NAMESPACE}/")
            logger.info(summary(metrics, mode_of(kwargs["policy"].config), task))
        return metrics

    eval_one_with_episode_metrics._ccdp_episode_metrics = True
    lerobot_eval.eval_one = eval_one_with_episode_metrics
    install_mode_job_name()


class _DropMessage(logging.Filter):
    def __init__(self, start: str):
        super().__init__()
        self.start = start

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith(self.start)


def install_mode_job_name() -> None:
    """Wrap EvalPipelineConfig.__post_init__ once: without `--job_name`, a ccdp policy's job is named
    `<env>_<policy>_<mode>` (`ccdp_ccdp_dp_star`), and so is the default output folder
    (`outputs/eval/<date>/<time>_<job name>`); an `--output_dir` given is kept. The policy's config, and so
    its mode, is only known once LeRobot's own __post_init__ has read `--policy.path`, so the name is changed
    after it, and LeRobot's "No job name provided, using ..." is said once, with the name used."""
    import lerobot.configs.eval as eval_config

    original = eval_config.EvalPipelineConfig.__post_init__
    if getattr(original, "_ccdp_mode_job_name", False):
        return
    no_name = "No job name provided"

    @functools.wraps(original)
    def post_init_naming_the_mode(self: eval_config.EvalPipelineConfig) -> None:
        named, placed = bool(self.job_name), bool(self.output_dir)
        quiet = _DropMessage(no_name)
        eval_config.logger.addFilter(quiet)
        try:
            original(self)
        finally:
            eval_config.logger.removeFilter(quiet)
        if named:
            return
        default = self.job_name
        if getattr(self.policy, "recovery_mode", None):
            self.job_name = f"{default}_{mode_of(self.policy)}"
            if not placed:  # LeRobot's `<time>_<job name>`, keeping its time
                self.output_dir = self.output_dir.with_name(
                    self.output_dir.name.removesuffix(default) + self.job_name
                )
        eval_config.logger.warning(f"{no_name}, using '{self.job_name}' as job name.")

    post_init_naming_the_mode._ccdp_mode_job_name = True
    eval_config.EvalPipelineConfig.__post_init__ = post_init_naming_the_mode
