"""A pool of chunks the frozen base sampled at demonstrated states, for training the failure-set classifier on them.

Drawing a batch of chunks costs a whole reverse diffusion (about twice a classifier step's time at batch 64 on a
2-core CPU), so the classifier stage refreshes the pool with the current batch's states only every
`classifier_resample_every` steps and trains on rows drawn from the pool. Every pooled chunk stays an exact draw of
the base at its state; reuse only lowers how many distinct draws the classifier sees.
"""

import torch
from torch import Tensor

# The pool holds this many training batches of rows; the oldest rows are overwritten first.
POOL_BATCHES = 16


class BaseSamplePool:
    """Ring buffer of (state condition, sampled chunk) rows, filled on the training device."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        self.state: Tensor | None = None
        self.chunk: Tensor | None = None
        self.size = 0
        self._next = 0

    def add(self, state: Tensor, chunk: Tensor) -> None:
        """Store rows (R, state_dim) and their chunks (R, horizon, A), overwriting the oldest rows when full."""
        if self.state is None:
            self.state = state.new_zeros(self.capacity, *state.shape[1:])
            self.chunk = chunk.new_zeros(self.capacity, *chunk.shape[1:])
        index = (self._next + torch.arange(state.shape[0], device=state.device)) % self.capacity
        self.state[index], self.chunk[index] = state, chunk
        self._next = int(index[-1] + 1) % self.capacity
        self.size = min(self.size + state.shape[0], self.capacity)

    def draw(self, rows: int) -> tuple[Tensor, Tensor]:
        """`rows` stored rows drawn uniformly with replacement: (states, chunks)."""
        if self.size == 0:
            raise RuntimeError("The base-sample pool is empty: add() a batch before draw().")
        index = torch.randint(0, self.size, (rows,), device=self.state.device)
        return self.state[index], self.chunk[index]
