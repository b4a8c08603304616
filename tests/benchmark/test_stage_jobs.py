"""`pipeline --jobs`: a task's evaluations side by side, each with its share of the cores' threads."""

import sys
import threading
from pathlib import Path

import pytest

from lerobot_ccdp.benchmark.pipeline import run_at_once, run_with_progress


def test_stages_run_jobs_at_a_time():
    both = threading.Barrier(2, timeout=120)  # broken if the second stage waits for the first to end
    ended = []
    run_at_once(2, [lambda: ended.append(both.wait()), lambda: ended.append(both.wait())])
    assert sorted(ended) == [0, 1]


def test_one_at_a_time_a_failure_stops_the_stages_after_it():
    started = []

    def fail():
        started.append("fail")
        raise RuntimeError("stage failed")

    with pytest.raises(RuntimeError, match="stage failed"):
        run_at_once(1, [lambda: started.append("first"), fail, lambda: started.append("after")])
    assert started == ["first", "fail"]


def test_side_by_side_a_failure_is_raised_once_the_running_stage_has_ended():
    started, gate, log = threading.Event(), threading.Event(), []

    def fail():
        started.wait()
        gate.set()
        raise RuntimeError("stage failed")

    def running():
        started.set()
        gate.wait()
        log.append("ended")

    with pytest.raises(RuntimeError, match="stage failed"):
        run_at_once(2, [fail, running])
    assert log == ["ended"]


def test_a_stage_side_by_side_gets_its_share_of_the_threads(tmp_path: Path):
    log = tmp_path / "stage.log"
    show = "import os; print(os.environ['OMP_NUM_THREADS'], os.environ['MKL_NUM_THREADS'])"
    command = [sys.executable, "-c", show]
    assert run_with_progress(command, log, "stage", threads=1) == 0
    assert log.read_text().split() == ["1", "1"]
