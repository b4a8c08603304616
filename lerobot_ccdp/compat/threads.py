"""Torch's CPU threads for a CCDP policy: one core left to whatever else runs on the machine.

torch starts one OpenMP thread per core, and a step waits at every parallel region for its slowest thread:
with every core taken, a thread whose core another process holds (a user's laptop is never idle) stalls them
all (docs/benchmarks.md, Speed: `python -m lerobot_ccdp.benchmark.throughput --threads 1|2 --beside`). So a
policy made on the CPU (lerobot-train, lerobot-eval, a robot loop) runs with one thread fewer than torch's
default, at least one, unless the user chose: OMP_NUM_THREADS or MKL_NUM_THREADS set, or torch's count changed
before.
"""

import logging
import os

import torch

_DEFAULT = torch.get_num_threads()  # torch's own choice, read when this module is first imported
_chosen = False


def leave_a_core(device: str) -> None:
    """Set torch's threads to one fewer than its default, once per process, on the CPU, if nobody chose."""
    global _chosen
    if _chosen or device != "cpu":  # a GPU's policy leaves the CPU threads to the user
        return
    _chosen = True
    user_chose = any(v in os.environ for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"))
    if user_chose or torch.get_num_threads() != _DEFAULT or _DEFAULT < 2:
        return
    torch.set_num_threads(_DEFAULT - 1)
    logging.info(
        f"CCDP runs torch on {_DEFAULT - 1} of {_DEFAULT} threads, leaving a core to other processes "
        "(set OMP_NUM_THREADS to choose)"
    )
