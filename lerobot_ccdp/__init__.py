"""CCDP for LeRobot: importing this package registers the `ccdp` policy type and the `ccdp` env type.

Layers, lowest first; a module imports its own layer or lower ones, never a higher one (tests/test_layers.py):
`policy` (what runs at every control step), `envs` (the tasks), `datasets` (recording, recipe files),
`recovery` (synthesis over datasets and checkpoints), `benchmark`. `compat` holds LeRobot's patches, each
written for the layer it adapts, beside the order.
"""

from lerobot_ccdp.compat.cli_errors import install_error_surfacing
from lerobot_ccdp.compat.config_help import install_source_cache
from lerobot_ccdp.compat.eval_metrics import install_episode_metrics
from lerobot_ccdp.compat.failure_passthrough import install_failure_passthrough
from lerobot_ccdp.compat.frame_columns import install_frame_columns
from lerobot_ccdp.compat.headless import choose_headless_gl
from lerobot_ccdp.envs import CCDPEnvConfig  # noqa: F401  (registers the `ccdp` env type and the gym ids)
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig

# before anything imports mujoco (no import above does: tests/compat/test_plugin_import.py)
choose_headless_gl()
install_error_surfacing()
install_source_cache()
install_failure_passthrough()
install_episode_metrics(import_eval=False)
install_frame_columns()

__all__ = ["CCDPConfig"]
