"""`image_free_episodes`: an episode without images is saved without LeRobot's row-by-row image pass, to the
same files; an episode with images still gets its image bytes embedded."""

from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from lerobot.datasets import lerobot_dataset
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_ccdp.compat.episode_writes import image_free_episodes

STATE_ONLY = {
    "observation.state": {"dtype": "float32", "shape": (3,), "names": None},
    "action": {"dtype": "float32", "shape": (4, 2), "names": None},
}


def write(root: Path, features: dict, frames: list[dict]) -> Path:
    dataset = LeRobotDataset.create(
        "local/episode_writes", fps=10, features=features, root=root, use_videos=False
    )
    for frame in frames:
        dataset.add_frame({**frame, "task": "t"})
    dataset.save_episode()
    dataset.finalize()
    return next((root / "data").rglob("*.parquet"))


def test_a_state_only_episode_is_saved_to_the_same_table_without_the_image_pass(tmp_path, monkeypatch):
    rng = np.random.default_rng(0)
    frames = [{k: rng.random(v["shape"], dtype=np.float32) for k, v in STATE_ONLY.items()} for _ in range(5)]
    plain = pq.read_table(write(tmp_path / "plain", STATE_ONLY, frames))
    calls = []
    original = lerobot_dataset.embed_images
    monkeypatch.setattr(lerobot_dataset, "embed_images", lambda d: calls.append(d) or original(d))
    counted = lerobot_dataset.embed_images
    with image_free_episodes():
        fast = pq.read_table(write(tmp_path / "fast", STATE_ONLY, frames))
    assert calls == []  # LeRobot's pass was skipped
    assert lerobot_dataset.embed_images is counted  # and put back after the block
    assert fast.equals(plain)


def test_an_episode_with_images_still_embeds_them(tmp_path):
    features = {**STATE_ONLY, "observation.image": {"dtype": "image", "shape": (8, 8, 3), "names": None}}
    rng = np.random.default_rng(0)
    frames = [
        {
            **{k: rng.random(v["shape"], dtype=np.float32) for k, v in STATE_ONLY.items()},
            "observation.image": rng.integers(0, 255, (8, 8, 3), dtype=np.uint8),
        }
        for _ in range(2)
    ]
    with image_free_episodes():
        table = pq.read_table(write(tmp_path / "images", features, frames))
    images = table.column("observation.image").to_pylist()
    assert all(image["bytes"] for image in images)  # the PNG bytes are in the table, not only a path
