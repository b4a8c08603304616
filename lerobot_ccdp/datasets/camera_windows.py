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
    """`torchcodec` where it loads (it needs the system's FFmpeg libraries), else `pyav` (FFmpeg in its
    wheel).

    LeRobot picks torchcodec whenever the package is installed, even where it cannot load; decided by trying.
    """
    try:
        import torchcodec.decoders  # noqa: F401
    except (ImportError, OSError, RuntimeError) as error:
        logger.info("torchcodec cannot load (%s); decoding videos with pyav", str(error).splitlines()[0])
        return "pyav"
    return "torchcodec"


class CameraWindows:
    """Images (len(frames), n_obs_steps, C, H, W) in [0, 1] per camera: the observation window ending at each
    dataset frame index in `frames`, padded at episode starts as LeRobotDataset pads (repeating the first
    frame).

    The dataset is opened once and read for every batch of synthesised states."""

    def __init__(self, meta: LeRobotDatasetMetadata, cameras: list[str], n_obs_steps: int):
        missing = [key for key in cameras if key not in meta.features]
        if missing:
            raise ValueError(
                f"Dataset {meta.repo_id!r} at {meta.root} lacks the camera(s) {missing} the checkpoint "
                f"encodes (it has {sorted(meta.features)}). Synthesise from the dataset the base was "
                "trained on."
            )
        self.cameras, self.n_obs_steps = cameras, n_obs_steps
        window = [step / meta.fps for step in range(1 - n_obs_steps, 1)]
        self.dataset = LeRobotDataset(
            meta.repo_id,
            root=meta.root,
            delta_timestamps=dict.fromkeys(cameras, window),
            video_backend=video_backend(),
        )

    def __call__(self, frames: Tensor) -> dict[str, Tensor]:
        items = [self.dataset[int(i)] for i in frames]
        # LeRobot squeezes a one-frame window of video to (C, H, W): restore the window axis.
        return {
            key: torch.stack([item[key].reshape(self.n_obs_steps, *item[key].shape[-3:]) for item in items])
            for key in self.cameras
        }
