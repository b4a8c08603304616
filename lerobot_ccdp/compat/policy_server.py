"""`lerobot-ccdp-policy-server`: LeRobot's async-inference policy server, serving ccdp too.

LeRobot's server refuses policy types outside a built-in list and never imports plugins. This entry point
imports the plugin (registering `ccdp`), adds `ccdp` to that list in place and runs LeRobot's own `serve`,
so the server's code, flags and LeRobot's robot client stay exactly LeRobot's.
"""

from types import ModuleType

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


def main() -> None:
    """Same flags as `python -m lerobot.async_inference.policy_server` (--host, --port, --fps, ...)."""
    server = lerobot_policy_server()
    allow_ccdp(server)
    server.serve()


if __name__ == "__main__":
    main()
