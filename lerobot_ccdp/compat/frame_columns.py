"""Training windows read from tensors instead of through `datasets` row access.

LeRobot 0.4.4's `LeRobotDataset._query_hf_dataset` reads each key of a frame's window (`delta_timestamps`:
the 32 actions of a chunk) with a `datasets` row query, which deep-copies the dataset's features and converts
the rows to torch on every call: about two thirds of a state policy's training step on 2 cores
(docs/benchmarks.md, "Training on 2 cores"). `install_frame_columns` wraps that method so each numeric column
is converted to one tensor the first time it is queried and windows are indexed from it: the same values and
dtypes (the column passes through the dataset's own torch transform once), without the per-call copies.

Only numeric columns are held (images and videos keep LeRobot's path), and the tensors belong to the
`hf_dataset` object they came from: a dataset whose `hf_dataset` is replaced or grows (recording) reads its
columns again. Installed where `_query_hf_dataset` has the signature this was written against (detected, not
by version); elsewhere LeRobot's own method runs unchanged.
"""

from __future__ import annotations

import functools
import inspect
import weakref
from typing import Any

import torch

NUMERIC = {"float32", "float64", "int64", "int32", "int16", "int8", "uint8", "bool"}
_CACHE = "_ccdp_frame_columns"


def _columns(dataset: Any) -> dict[str, torch.Tensor]:
    """This dataset's numeric columns as tensors, read again when its `hf_dataset` changed."""
    hf = dataset.hf_dataset
    held = getattr(dataset, _CACHE, None)
    if held is None or held[0]() is not hf or held[1] != len(hf):
        held = (weakref.ref(hf), len(hf), {})
        setattr(dataset, _CACHE, held)
    return held[2]


def _column(dataset: Any, key: str) -> torch.Tensor | None:
    """Column `key` as one tensor (frames first), or None where it is not numeric."""
    if dataset.meta.features.get(key, {}).get("dtype") not in NUMERIC:
        return None
    columns = _columns(dataset)
    if key not in columns:  # every row, read the way LeRobot reads a window (its transform to torch)
        hf, rows = dataset.hf_dataset, list(range(len(dataset.hf_dataset)))
        try:
            columns[key] = torch.stack(hf[key][rows])
        except (KeyError, TypeError, IndexError):
            columns[key] = torch.stack(hf[rows][key])
    return columns[key]


def install_frame_columns() -> None:
    """Wrap `LeRobotDataset._query_hf_dataset` (once) where its shape is the one known here."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    original = getattr(LeRobotDataset, "_query_hf_dataset", None)
    if original is None or getattr(original, "_ccdp_wrapped", False):
        return
    if list(inspect.signature(original).parameters) != ["self", "query_indices"]:
        return

    @functools.wraps(original)
    def query(self: Any, query_indices: dict[str, list[int]]) -> dict:
        result, rest = {}, {}
        for key, q_idx in query_indices.items():
            column = None if key in self.meta.video_keys else _column(self, key)
            if column is None:
                rest[key] = q_idx
                continue
            relative = (
                q_idx
                if self._absolute_to_relative_idx is None
                else [self._absolute_to_relative_idx[i] for i in q_idx]
            )
            result[key] = column[relative]
        return {**result, **(original(self, rest) if rest else {})}

    query._ccdp_wrapped = True
    LeRobotDataset._query_hf_dataset = query
