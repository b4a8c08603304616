"""`lerobot-ccdp-policy-server`: LeRobot's async-inference policy server, serving ccdp too.

LeRobot's server refuses policy types outside a built-in list and never imports plugins. This entry point
imports the plugin (registering `ccdp`), adds `ccdp` to that list in place and runs LeRobot's own `serve`,
so the server's code, flags and LeRobot's robot client stay exactly LeRobot's.

It serves LeRobot's server class with checks made where the client's messages enter (`checked_server`):
LeRobot's own server accepted `actions_per_chunk=0` and failed later, and answered an observation that lacks
one of the robot's keys with an empty reply and the key alone in its log (`'y'`).
"""

import functools
import json
import pickle  # nosec: LeRobot's async protocol pickles its messages
from pathlib import Path
from types import ModuleType
from typing import Any

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType
from lerobot.datasets.utils import DEFAULT_FEATURES, dataset_to_policy_features
from lerobot.utils.constants import OBS_IMAGES, OBS_STR
from lerobot.utils.utils import is_torch_device_available

from lerobot_ccdp.compat.cli_errors import buried_error
from lerobot_ccdp.compat.env_fit import described, feature_mismatches
from lerobot_ccdp.policy.configuration_ccdp import FAILURE_FEATURE_KEY, CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import (
    CCDPPolicy,  # importing the package registers the ccdp policy type
)

INSTALL_HINT = "pip install 'lerobot_policy_ccdp[async]' (or pip install 'lerobot[async]')"


def lerobot_policy_server() -> ModuleType:
    """LeRobot's policy server module; it needs gRPC, which only LeRobot's `async` extra installs."""
    try:
        from lerobot.async_inference import policy_server
    except ModuleNotFoundError as error:
        raise SystemExit(
            f"LeRobot's async inference needs the {error.name!r} package: {INSTALL_HINT}"
        ) from error
    return policy_server


def supported_policies(server: ModuleType) -> list[str]:
    """The list the server checks a requested policy type against, found by what it holds (LeRobot's built-in
    `diffusion` among strings) rather than by its name, which LeRobot may change between versions."""
    for value in vars(server).values():
        if (
            isinstance(value, list)
            and value
            and all(isinstance(v, str) for v in value)
            and "diffusion" in value
        ):
            return value
    raise RuntimeError(
        f"{server.__name__} has no list of supported policy types (one holding 'diffusion'); this LeRobot's "
        "async server is not the one lerobot_policy_ccdp knows. Serve ccdp in your own process with "
        "CCDPPolicy.from_pretrained (docs/robot.md), or use a LeRobot version in this package's range."
    )


def allow_ccdp(server: ModuleType) -> None:
    """Adds `ccdp` in place: the server module refers to the same list object, so it sees the change."""
    supported = supported_policies(server)
    if CCDPPolicy.name not in supported:
        supported.append(CCDPPolicy.name)


def robot_keys(lerobot_features: dict[str, dict], cameras: bool = True) -> list[str]:
    """The keys of the robot's raw observation that LeRobot's server reads (`build_dataset_frame`): the name
    of every value of a 1-D float feature, and (with `cameras`) each camera's name."""
    keys = []
    for key, feature in lerobot_features.items():
        if key in DEFAULT_FEATURES or not key.startswith(OBS_STR):
            continue
        if feature["dtype"] in ("image", "video"):
            keys += [key.removeprefix(f"{OBS_IMAGES}.")] if cameras else []
        elif feature["dtype"] == "float32" and len(feature["shape"]) == 1:
            keys.extend(feature["names"])
    return keys


def refuse_unfit_setup(specs: Any) -> None:
    """Refuse the client's policy instructions before the server changes anything: `actions_per_chunk` out of
    range, a device the machine lacks, a ccdp checkpoint asked for as another type, a ccdp config whose own
    checks fail, or a checkpoint whose inputs the robot's features lack."""
    chunk = specs.actions_per_chunk
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ValueError(
            f"actions_per_chunk={chunk!r}: the number of actions the server sends per observation must be an "
            "integer >= 1. Set the robot client's --actions_per_chunk."
        )
    try:  # LeRobot's server moved the policy there and failed in torch's words ("Found no NVIDIA driver")
        available = is_torch_device_available(specs.device)
    except ValueError as error:  # a name torch does not know
        raise ValueError(
            f"device={specs.device!r}: {error} Set the robot client's --policy_device."
        ) from None
    if not available:
        raise ValueError(
            f"device={specs.device!r} is not available on the server's machine. Set the robot client's "
            "--policy_device to one it has (cpu always is)."
        )
    path = specs.pretrained_name_or_path
    if specs.policy_type != CCDPPolicy.name:
        if _local_type(path) == CCDPPolicy.name:  # LeRobot's class for the named type fails on its fields
            raise ValueError(
                f"The policy at {path} is a {CCDPPolicy.name} checkpoint, but the client asked for policy "
                f"type {specs.policy_type!r}. Set the robot client's --policy_type={CCDPPolicy.name}."
            )
        return
    try:
        config = PreTrainedConfig.from_pretrained(path)
    except Exception as error:  # the config's own message, not draccus's "Couldn't instantiate"
        where = (
            ""
            if Path(path).exists()
            else f" (no file or folder {path} exists on the server's machine: the client's "
            "--pretrained_name_or_path names a checkpoint folder there, or a Hub repo id)"
        )
        raise ValueError(
            f"The policy at {path} cannot be served: {buried_error(error) or error}{where}"
        ) from error
    if not isinstance(config, CCDPConfig):
        return  # CCDPPolicy.from_pretrained names another policy type with the fix
    if chunk > config.n_action_steps:
        raise ValueError(
            f"actions_per_chunk={chunk}: {path} plans {config.n_action_steps} actions per observation "
            f"(n_action_steps), so the server can send 1 to {config.n_action_steps}. Set the robot client's "
            "--actions_per_chunk in that range."
        )
    provided = {
        specs.rename_map.get(key, key): feature
        for key, feature in dataset_to_policy_features(specs.lerobot_features).items()
    }
    # The server resizes each camera to the policy's image size: only its presence counts.
    provided |= {
        key: config.input_features[key]
        for key, feature in provided.items()
        if feature.type is FeatureType.VISUAL and key in config.input_features
    }
    inputs = {k: f for k, f in config.input_features.items() if k != FAILURE_FEATURE_KEY}
    mismatches = feature_mismatches(inputs, provided)
    if mismatches:
        raise ValueError(
            f"{path} does not fit the robot the client describes: {described(mismatches, 'robot')}. Serve a "
            "checkpoint trained on this robot's observations, or map the robot's keys with the client's "
            "rename_map."
        )


def _local_type(path: str) -> str | None:
    """The policy type a local checkpoint folder's config.json names (None for a Hub id or no such file)."""
    try:
        return json.loads((Path(path) / "config.json").read_text()).get("type")
    except (OSError, ValueError, AttributeError):
        return None


def _not_a_number(value: Any) -> bool:
    """Whether a robot's value cannot be read as the float LeRobot's server makes of it."""
    try:
        float(value)
    except (TypeError, ValueError):
        return True
    return isinstance(value, bool)


@functools.cache
def checked_server(base: type) -> type:
    """LeRobot's server class `base`, refusing bad policy instructions and incomplete observations with a
    message that names the setting or keys, logged and raised the way the server reports its own errors (the
    client's call fails with it)."""
    from lerobot.async_inference.helpers import RemotePolicyConfig

    class CheckedPolicyServer(base):
        def SendPolicyInstructions(self, request, context):  # noqa: N802 (gRPC's name)
            if self.running:
                specs = pickle.loads(request.data)  # nosec: as LeRobot's own handler reads it
                if isinstance(specs, RemotePolicyConfig):
                    self._refuse(refuse_unfit_setup, specs)
            return super().SendPolicyInstructions(request, context)

        def _enqueue_observation(self, obs) -> bool:
            self._refuse(self._refuse_incomplete, obs.get_observation())
            return super()._enqueue_observation(obs)

        def _refuse_incomplete(self, observation: dict) -> None:
            if self.lerobot_features is None:
                raise ValueError(
                    "An observation arrived before any policy was set up: the client sends its policy "
                    "instructions (SendPolicyInstructions) first."
                )
            expected = robot_keys(self.lerobot_features)
            missing = [key for key in expected if key not in observation]
            if missing:
                raise ValueError(
                    f"The observation lacks {missing}: the client described the robot with the keys "
                    f"{expected}, and each observation must hold them all. Send every key, or set the "
                    "policy up again with the robot's features."
                )
            wrong = {
                key: observation[key]
                for key in robot_keys(self.lerobot_features, cameras=False)
                if _not_a_number(observation[key])
            }
            if wrong:
                raise ValueError(
                    f"The observation's {wrong} are not numbers: each of the robot's state keys holds one "
                    "number (a camera's key, an image). Send numbers."
                )

        def _refuse(self, check, *args) -> None:
            try:
                check(*args)
            except ValueError as error:
                self.logger.error(str(error))
                raise

    CheckedPolicyServer.__name__ = CheckedPolicyServer.__qualname__ = base.__name__
    return CheckedPolicyServer


def main() -> None:
    """Same flags as `python -m lerobot.async_inference.policy_server` (--host, --port, --fps, ...)."""
    server = lerobot_policy_server()
    allow_ccdp(server)
    server.PolicyServer = checked_server(server.PolicyServer)  # serve() builds it by this name
    server.serve()


if __name__ == "__main__":
    main()
