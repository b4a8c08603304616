"""CCDP for LeRobot: importing this package registers the `ccdp` policy type and the `ccdp` env type."""

from lerobot_ccdp.cli_errors import install_error_surfacing
from lerobot_ccdp.configuration_ccdp import CCDPConfig
from lerobot_ccdp.envs import CCDPEnvConfig  # noqa: F401  (registers the `ccdp` env type and the gym ids)
from lerobot_ccdp.eval_metrics import install_episode_metrics
from lerobot_ccdp.failure_passthrough import install_failure_passthrough
from lerobot_ccdp.headless import choose_headless_gl

choose_headless_gl()  # before anything imports mujoco (no import above does: tests/test_plugin_import.py)
install_error_surfacing()
install_failure_passthrough()
install_episode_metrics(import_eval=False)

__all__ = ["CCDPConfig"]
