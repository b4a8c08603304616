"""Camera frames of demo datasets for recovery synthesis: the images of the frames whose state is perturbed.

Eq. (6) perturbs the low-dimensional state only; the frame's own images are reused as they were recorded, so
synthesis reads (and decodes) just the images of the `n_states` demo frames it samples around.
"""

from __future__ import annotations

import functools
import logging

import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from torch import Tensor

logger = logging.getLogger(__name__)


@functools.cache
def video_backend() -> str:
    """`torchcodec` where it loads (it needs the system's FFmpeg libraries), else `pyav` (FFmpeg in its wheel).

    LeRobot picks torchcodec whenever the package is installed, even where it cannot load; decided by trying.
    """
    try:
        import torchcodec.decoders  # noqa: F401
    except (ImportError, OSError, RuntimeError) as error:
        logger.info("torchcodec cannot load (%s); decoding videos with pyav", str(error).splitlines()[0])
        return "pyav"
    return "torchcodec"


def camera_windows(meta: LeRobotDatasetMetadata, cameras: list[str], frames: Tensor, n_obs_steps: int) -> dict[str, Tensor]:
    """Images (len(frames), n_obs_steps, C, H, W) in [0, 1] per camera: the observation window ending at each
    dataset frame index in `frames`, padded at episode starts as LeRobotDataset pads (repeating the first frame)."""
    missing = [key for key in cameras if key not in meta.features]
    if missing:
        raise ValueError(f"Dataset {meta.repo_id!r} at {meta.root} lacks the camera(s) {missing} the checkpoint "
                         f"encodes (it has {sorted(meta.features)}). Synthesise from the dataset the base was trained on.")
    window = [step / meta.fps for step in range(1 - n_obs_steps, 1)]
    dataset = LeRobotDataset(meta.repo_id, root=meta.root, delta_timestamps={key: window for key in cameras},
                             video_backend=video_backend())
    items = [dataset[int(i)] for i in frames]
    # LeRobot squeezes a one-frame window of video to (C, H, W): restore the window axis.
    return {key: torch.stack([item[key].reshape(n_obs_steps, *item[key].shape[-3:]) for item in items])
            for key in cameras}
