"""A CCDP policy on the CPU leaves one core to other processes, unless the user chose torch's threads."""

import pytest
import torch

from lerobot_ccdp.compat import threads

from fixtures.policy_factory import make_policy


@pytest.fixture
def fresh(monkeypatch):
    """torch at a default of 2 threads, no choice made yet; torch's count put back afterwards."""
    before = torch.get_num_threads()
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    monkeypatch.setattr(threads, "_DEFAULT", 2)
    monkeypatch.setattr(threads, "_chosen", False)
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)


def test_one_core_is_left_once(fresh):
    threads.leave_a_core("cpu")
    assert torch.get_num_threads() == 1
    torch.set_num_threads(2)  # a later policy in the same process does not take another
    threads.leave_a_core("cpu")
    assert torch.get_num_threads() == 2


@pytest.mark.parametrize("variable", ["OMP_NUM_THREADS", "MKL_NUM_THREADS"])
def test_a_users_thread_setting_is_kept(fresh, monkeypatch, variable):
    monkeypatch.setenv(variable, "2")
    threads.leave_a_core("cpu")
    assert torch.get_num_threads() == 2


def test_a_count_changed_before_and_a_gpu_policy_are_left_alone(fresh):
    threads.leave_a_core("cuda")
    assert torch.get_num_threads() == 2
    torch.set_num_threads(3)
    threads.leave_a_core("cpu")
    assert torch.get_num_threads() == 3


def test_a_cpu_policy_leaves_a_core_when_made(fresh):
    make_policy()
    assert torch.get_num_threads() == 1
