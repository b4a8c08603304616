"""Plugin shim: LeRobot imports this module by distribution name; importing lerobot_ccdp registers
everything."""

import lerobot_ccdp  # noqa: F401
