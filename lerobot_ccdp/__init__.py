"""CCDP for LeRobot: importing this package registers the `ccdp` policy type and the `ccdp` env type."""

from lerobot_ccdp.configuration_ccdp import CCDPConfig

__all__ = ["CCDPConfig"]
