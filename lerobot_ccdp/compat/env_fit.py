"""lerobot-eval refuses a checkpoint that does not fit the env before the first step, naming every feature.

LeRobot's `make_policy` replaces a checkpoint's output features with the env's but keeps its input features,
and checks neither against the env: a DoorOpening checkpoint evaluated on ButtonSearch (an environment state
of 3 against 8 values) built the policy, started the rollout and died in the normaliser ("size 8 vs 3"). This
module wraps `lerobot_eval.make_policy` (installed by a `ccdp` env config, which lerobot-eval parses before
it builds anything) to compare the features the policy will keep with the env's, as `make_policy` will see
them (renamed by `--rename_map`, images channel-first), before the policy is loaded. Envs of other packages
are left to LeRobot.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

from lerobot.configs.types import PolicyFeature

from lerobot_ccdp.policy.configuration_ccdp import FAILURE_FEATURE_KEY

NUMPY_SEEDS = 2**32  # np.random.seed takes 0 to 2**32 - 1

if TYPE_CHECKING:
    from lerobot.configs.policies import PreTrainedConfig

    from lerobot_ccdp.envs.configuration_env import CCDPEnvConfig


def feature_mismatches(
    policy: dict[str, PolicyFeature], provided: dict[str, PolicyFeature]
) -> dict[str, tuple[tuple | None, tuple | None]]:
    """Key -> (the policy's shape, the provided shape) of each feature the policy takes whose shape differs
    from what is provided; None on the side that lacks the feature."""
    mismatches = {}
    for key, feature in policy.items():
        given = provided.get(key)
        shape, given_shape = tuple(feature.shape), None if given is None else tuple(given.shape)
        if shape != given_shape:
            mismatches[key] = (shape, given_shape)
    return mismatches


def described(mismatches: dict[str, tuple[tuple | None, tuple | None]], where: str) -> str:
    """One clause per feature: "observation.environment_state has shape (3,) in the checkpoint and (8,) in
    the env"."""
    return "; ".join(
        f"{key} has shape {ours} in the checkpoint and {theirs} in the {where}"
        if theirs is not None
        else f"{key} (shape {ours} in the checkpoint) is missing from the {where}"
        for key, (ours, theirs) in mismatches.items()
    )


def policy_view(env_cfg: Any, rename_map: dict[str, str] | None) -> dict[str, PolicyFeature]:
    """The env's features as `make_policy` hands them to the policy: LeRobot's policy keys, renamed."""
    from lerobot.envs.utils import env_to_policy_features

    renames = rename_map or {}
    return {renames.get(key, key): feature for key, feature in env_to_policy_features(env_cfg).items()}


def refuse_unfit_checkpoint(
    policy_cfg: PreTrainedConfig, env_cfg: CCDPEnvConfig, rename_map: dict[str, str] | None = None
) -> None:
    """Refuse a policy config whose features (those `make_policy` keeps: the inputs, and the action it will
    replace) differ from the env's, naming each with both shapes and the tasks the checkpoint does fit."""
    from lerobot_ccdp.envs.tasks import TASKS  # here: the envs package imports this module

    mismatches = _mismatches(policy_cfg, env_cfg, rename_map)
    if not mismatches:
        return
    fitting = [t for t in TASKS if not _mismatches(policy_cfg, _with_task(env_cfg, t), rename_map)]
    fix = (
        f"The checkpoint fits --env.task={' or '.join(fitting)}: evaluate it there, or use a checkpoint "
        f"trained on {env_cfg.task}."
        if fitting
        else f"No ccdp task with these env settings fits it: use a checkpoint trained on {env_cfg.task}, "
        "with the same --env.obs_type and cameras."
    )
    policy = f"The checkpoint {policy_cfg.pretrained_path}" if policy_cfg.pretrained_path else "The policy"
    raise ValueError(
        f"{policy} does not fit --env.task={env_cfg.task} "
        f"(--env.obs_type={env_cfg.obs_type}): {described(mismatches, 'env')}. {fix}"
    )


def _mismatches(
    policy_cfg: PreTrainedConfig, env_cfg: CCDPEnvConfig, rename_map: dict[str, str] | None
) -> dict[str, tuple[tuple | None, tuple | None]]:
    provided = policy_view(env_cfg, rename_map)
    # make_policy takes the env's inputs where the config names none; it always takes the env's action. The
    # policy acts one step at a time, whatever chunk a recovery dataset stored per frame; a ccdp policy makes
    # its failure feature z itself.
    inputs = {k: f for k, f in policy_cfg.input_features.items() if k != FAILURE_FEATURE_KEY}
    actions = {k: PolicyFeature(f.type, tuple(f.shape)[-1:]) for k, f in policy_cfg.output_features.items()}
    return feature_mismatches({**inputs, **actions}, provided)


def _with_task(env_cfg: CCDPEnvConfig, task: str) -> CCDPEnvConfig:
    """The same env settings on another task."""
    return type(env_cfg)(
        task=task,
        obs_type=env_cfg.obs_type,
        cameras=list(env_cfg.cameras),
        observation_width=env_cfg.observation_width,
        observation_height=env_cfg.observation_height,
        render_mode=None,
    )


def refuse_unusable_seed(seed: Any) -> None:
    """Refuse a `--seed` numpy cannot take (lerobot-eval seeds numpy with it first, and failed 130 lines into
    numpy's `_legacy_seeding` with no flag named)."""
    if seed is not None and not (isinstance(seed, int) and 0 <= seed < NUMPY_SEEDS):
        raise ValueError(
            f"--seed={seed}: lerobot-eval seeds numpy with it, which takes 0 to {NUMPY_SEEDS - 1}; choose a "
            "seed in that range (episode i is seeded seed + i)."
        )


def install_env_fit_check() -> None:
    """Wrap lerobot_eval.make_policy, set_seed and make_env once (eval_main looks them up at call time);
    other envs pass through make_policy."""
    import lerobot.scripts.lerobot_eval as lerobot_eval

    original = lerobot_eval.make_policy
    if getattr(original, "_ccdp_env_fit", False):
        return
    set_seed = lerobot_eval.set_seed

    @functools.wraps(set_seed)
    def set_usable_seed(seed: Any, *args: Any, **kwargs: Any) -> None:
        refuse_unusable_seed(seed)
        set_seed(seed, *args, **kwargs)

    lerobot_eval.set_seed = set_usable_seed
    make_env = lerobot_eval.make_env

    @functools.wraps(make_env)
    def make_some_envs(env_cfg: Any, *args: Any, n_envs: int = 1, **kwargs: Any) -> Any:
        if n_envs < 1:  # LeRobot's own words name `n_envs`, no flag
            raise ValueError(
                f"--eval.batch_size={n_envs}: lerobot-eval runs that many envs side by side; give at least 1 "
                "(and at most --eval.n_episodes)."
            )
        return make_env(env_cfg, *args, n_envs=n_envs, **kwargs)

    lerobot_eval.make_env = make_some_envs

    @functools.wraps(original)
    def make_policy_fitting_the_env(cfg: PreTrainedConfig, *args: Any, **kwargs: Any):
        from lerobot_ccdp.envs.configuration_env import CCDPEnvConfig

        env_cfg = kwargs.get("env_cfg")
        if isinstance(env_cfg, CCDPEnvConfig):
            refuse_unfit_checkpoint(cfg, env_cfg, kwargs.get("rename_map"))
        return original(cfg, *args, **kwargs)

    make_policy_fitting_the_env._ccdp_env_fit = True
    lerobot_eval.make_policy = make_policy_fitting_the_env
