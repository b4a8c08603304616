"""LeRobotDataset.save_episode without its row-by-row pass over episodes that hold no image.

LeRobot 0.4.4 runs `embed_images` on every saved episode: a `datasets.map` over each row that embeds image
bytes, run even when no column holds an image. On the state-only rows the synthesis writes (chunks, sibling
outcomes) that pass took 16 of the 18 s one 1000-row episode took to save, most of the synthesis's writing
time (docs/benchmarks.md, Speed). Inside `image_free_episodes()`, an episode without an image column is saved
as is: the pass would have returned the same table (`datasets.table.embed_table_storage` embeds only the
columns for which `require_storage_embed` holds). Episodes with images, and a LeRobot without `embed_images`
in its dataset module, are left to LeRobot.
"""

from collections.abc import Iterator
from contextlib import contextmanager

import datasets
from datasets.features.features import require_storage_embed
from lerobot.datasets import lerobot_dataset


def holds_embeddable(dataset: datasets.Dataset) -> bool:
    """Whether any column of `dataset` holds data `embed_table_storage` would embed (images)."""
    return any(require_storage_embed(feature) for feature in dataset.features.values())


@contextmanager
def image_free_episodes() -> Iterator[None]:
    """Within the block, LeRobotDataset.save_episode skips the image pass for episodes without images."""
    original = getattr(lerobot_dataset, "embed_images", None)
    if original is None:  # a LeRobot that saves episodes another way: nothing to skip
        yield
        return

    def embed_images(dataset: datasets.Dataset) -> datasets.Dataset:
        return original(dataset) if holds_embeddable(dataset) else dataset

    lerobot_dataset.embed_images = embed_images
    try:
        yield
    finally:
        lerobot_dataset.embed_images = original
