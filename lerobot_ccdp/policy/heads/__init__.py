"""The recovery heads, one module each, and their registry (`registry.py`): `recovery_head` names one of
`HEADS`. Adding a head: docs/method.md, "Adding a recovery head"."""

from lerobot_ccdp.policy.heads import classifier, set_denoiser, unet  # noqa: F401  (each registers its head)
from lerobot_ccdp.policy.heads.registry import (
    HEADS,
    RecoveryHead,
    head_class,
    head_of,
    make_head,
    name_default_head,
    refuse_settings_of_other_heads,
)

__all__ = [
    "HEADS",
    "RecoveryHead",
    "head_class",
    "head_of",
    "make_head",
    "name_default_head",
    "refuse_settings_of_other_heads",
]
