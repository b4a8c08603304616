"""Training items read from tensors instead of through `datasets` row access.

LeRobot 0.4.4's `LeRobotDataset.__getitem__` reads a frame, and `_query_hf_dataset` each key of its window
(`delta_timestamps`: the 32 actions of a chunk), with `datasets` row queries that deep-copy the dataset's
features and convert the rows to torch on every call: two thirds of a state policy's base step and 40% of a
recovery step on 2 cores (docs/design_choices.md). `install_frame_columns` converts each numeric column to one
tensor the first time it is needed (one arrow read, typed as LeRobot's transform types it and checked against
LeRobot's own read of its first and last rows) and serves frames and windows from it:

- windows of numeric keys, in any dataset (`_query_hf_dataset`);
- whole items, in datasets with no videos, no image transforms and only numeric columns (`__getitem__`, the
  rest of LeRobot's item assembly reproduced). The first item of each dataset is also read LeRobot's way and
  compared: a LeRobot whose items differ (a newer version assembling them otherwise) keeps its own path for
  that dataset, with a warning.

The tensors belong to the `hf_dataset` object they came from: a dataset whose `hf_dataset` is replaced or
grows (recording) reads its columns again. Installed where the wrapped methods have the signatures this was
written against (detected, not by version); elsewhere LeRobot's own methods run unchanged.
"""

from __future__ import annotations

import functools
import inspect
import logging
import weakref
from typing import Any

import torch

logger = logging.getLogger(__name__)

NUMERIC = {"float32", "float64", "int64", "int32", "int16", "int8", "uint8", "bool"}
_CACHE = "_ccdp_frame_columns"


class _Held:
    """The columns read from one `hf_dataset`, and whether whole items may come from them."""

    def __init__(self, hf: Any):
        self.source, self.length = weakref.ref(hf), len(hf)
        self.columns: dict[str, torch.Tensor] = {}
        self.items: bool | None = None  # None: not yet compared with LeRobot's own first item
        self.tasks: list[str] | None = None  # meta.tasks' names by task_index

    def __reduce__(self) -> tuple:
        """A dataset sent to a DataLoader worker (pickled under `spawn`) arrives without its columns and reads
        them again there: the weak reference to the `hf_dataset` cannot be pickled, and the copy's
        `hf_dataset` is another object anyway."""
        return (type(None), ())


def _held(dataset: Any) -> _Held:
    """What is held for this dataset's current `hf_dataset`, read again when it changed."""
    hf, held = dataset.hf_dataset, getattr(dataset, _CACHE, None)
    if held is None or held.source() is not hf or held.length != len(hf):
        held = _Held(hf)
        setattr(dataset, _CACHE, held)
    return held


def _column(dataset: Any, key: str) -> torch.Tensor | None:
    """Column `key` as one tensor (frames first), or None where it is not numeric."""
    if dataset.meta.features.get(key, {}).get("dtype") not in NUMERIC:
        return None
    columns = _held(dataset).columns
    if key not in columns:
        columns[key] = _read_column(dataset.hf_dataset, key)
    return columns[key]


def _lerobot_rows(hf: Any, key: str, rows: list[int]) -> torch.Tensor:
    """Rows of column `key` the way LeRobot 0.4.4 reads a window (its transform to torch, then a stack)."""
    try:
        return torch.stack(hf[key][rows])
    except (KeyError, TypeError, IndexError):
        return torch.stack(hf[rows][key])


def _read_column(hf: Any, key: str) -> torch.Tensor:
    """Every row of column `key` as one tensor, read in one arrow-to-numpy pass and typed as LeRobot's
    transform types it (Python floats to torch's default dtype, integers to int64). Checked against LeRobot's
    own read of the first and last rows; where they differ, the whole column is read LeRobot's way."""
    array = torch.from_numpy(hf.select_columns([key]).with_format("numpy")[:][key])
    if array.dtype.is_floating_point:
        array = array.to(torch.get_default_dtype())
    elif array.dtype != torch.bool:
        array = array.to(torch.int64)
    ends = [0, len(hf) - 1]
    own = _lerobot_rows(hf, key, ends)
    if array.dtype == own.dtype and array.shape[1:] == own.shape[1:] and torch.equal(array[ends], own):
        return array
    logger.warning("lerobot_ccdp: column %s read LeRobot's way (its arrow read differs)", key)
    return _lerobot_rows(hf, key, list(range(len(hf))))


def _fast_items(dataset: Any) -> bool:
    """Whether whole items of `dataset` may come from its columns (not refused by the first item's check)."""
    if dataset.meta.video_keys or dataset.image_transforms is not None:
        return False
    held = _held(dataset)
    if held.items is False:
        return False
    names = dataset.hf_dataset.column_names
    # read every column once; only numeric ones are held
    if len(held.columns) != len(names) and not all(_column(dataset, key) is not None for key in names):
        held.items = False
    return held.items is not False


def _item(dataset: Any, idx: int) -> dict:
    """LeRobot 0.4.4's item assembly without videos or image transforms, from the column tensors."""
    held = _held(dataset)
    item = {key: held.columns[key][idx].clone() for key in dataset.hf_dataset.column_names}
    if dataset.delta_indices is not None:
        frame, episode = item["index"].item(), item["episode_index"].item()
        query_indices, padding = dataset._get_query_indices(frame, episode)
        item = {**item, **padding, **dataset._query_hf_dataset(query_indices)}
    if held.tasks is None:
        held.tasks = list(dataset.meta.tasks.index)
    item["task"] = held.tasks[item["task_index"].item()]
    if "subtask_index" in dataset.features and dataset.meta.subtasks is not None:
        item["subtask"] = dataset.meta.subtasks.iloc[item["subtask_index"].item()].name
    return item


def _same(a: dict, b: dict) -> bool:
    if a.keys() != b.keys():
        return False
    for key, value in a.items():
        other = b[key]
        if isinstance(value, torch.Tensor):
            if not (
                isinstance(other, torch.Tensor) and value.dtype == other.dtype and torch.equal(value, other)
            ):
                return False
        elif value != other:
            return False
    return True


def _wrap_query(original: Any) -> Any:
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

    return query


def _wrap_getitem(original: Any) -> Any:
    @functools.wraps(original)
    def getitem(self: Any, idx: Any) -> dict:
        load = getattr(self, "_ensure_hf_dataset_loaded", None)
        if load is None or not isinstance(idx, int):
            return original(self, idx)
        load()
        if not _fast_items(self):
            return original(self, idx)
        held = _held(self)
        if held.items is None:  # the first item both ways: this LeRobot must assemble items as copied here
            own = original(self, idx)
            held.items = _same(_item(self, idx), own)
            if not held.items:
                logger.warning(
                    "lerobot_ccdp: this LeRobot assembles dataset items differently from 0.4.4; reading %s "
                    "through LeRobot's own (slower) path.",
                    self.repo_id,
                )
            return own
        return _item(self, idx)

    return getitem


def install_frame_columns() -> None:
    """Wrap `LeRobotDataset._query_hf_dataset` and `__getitem__` (once) where their shapes are the ones known
    here."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    for name, wrap, parameters in (
        ("_query_hf_dataset", _wrap_query, ["self", "query_indices"]),
        ("__getitem__", _wrap_getitem, ["self", "idx"]),
    ):
        original = getattr(LeRobotDataset, name, None)
        if original is None or getattr(original, "_ccdp_wrapped", False):
            continue
        if list(inspect.signature(original).parameters) != parameters:
            continue
        wrapped = wrap(original)
        wrapped._ccdp_wrapped = True
        setattr(LeRobotDataset, name, wrapped)
