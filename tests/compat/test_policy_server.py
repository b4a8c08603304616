"""ccdp served by LeRobot's own async-inference policy server through `lerobot-ccdp-policy-server`.

The server runs as its own process (the module the console script calls) on 127.0.0.1 and a free port; the
test talks to it with the gRPC calls LeRobot's robot client makes, in its order: Ready, SendPolicyInstructions
(a pickled RemotePolicyConfig), SendObservations (a pickled TimedObservation in chunks), GetActions.
"""

import pickle  # nosec: LeRobot's async protocol pickles its messages
import socket
import subprocess
import sys
import time
from types import SimpleNamespace

import grpc
import lerobot.async_inference
import pytest
import torch
from lerobot.async_inference.helpers import RemotePolicyConfig, TimedAction, TimedObservation
from lerobot.datasets.utils import hw_to_dataset_features
from lerobot.transport import services_pb2, services_pb2_grpc
from lerobot.transport.utils import send_bytes_in_chunks
from lerobot.utils.constants import OBS_STR

from lerobot_ccdp.compat.policy_server import allow_ccdp, supported_policies

from fixtures.policy_factory import untrained_checkpoint

ACTIONS_PER_CHUNK = 5


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(autouse=True)
def _logs_in_tmp(tmp_path, monkeypatch):
    """LeRobot's server writes logs/ into the working directory when its module is imported."""
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def server(tmp_path):
    """The entry point in a subprocess; stopped (by its pid) when the test ends."""
    port = _free_port()
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "lerobot_ccdp.compat.policy_server",
            "--host=127.0.0.1",
            f"--port={port}",
            "--inference_latency=0",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,
    )
    channel = grpc.insecure_channel(f"127.0.0.1:{port}")
    try:
        while True:  # no wall-clock limit: only a server that died stops the wait
            try:
                grpc.channel_ready_future(channel).result(timeout=1)
                break
            except grpc.FutureTimeoutError:
                if process.poll() is not None:
                    pytest.fail(f"the policy server exited ({process.returncode}):\n{process.stdout.read()}")
        yield SimpleNamespace(stub=services_pb2_grpc.AsyncInferenceStub(channel), process=process)
    finally:
        channel.close()
        process.terminate()
        process.wait()


def test_ccdp_round_trip_through_lerobots_policy_server(server, reaching_root, tmp_path):
    checkpoint = untrained_checkpoint(
        reaching_root, tmp_path / "ckpt", failure_feature="primitive", num_primitives=4
    )
    # What the robot client sends for a robot with two motors x, y (map_robot_keys_to_lerobot_features).
    features = hw_to_dataset_features({"x": float, "y": float}, OBS_STR, use_video=False)
    specs = RemotePolicyConfig("ccdp", str(checkpoint), features, ACTIONS_PER_CHUNK, "cpu")

    server.stub.Ready(services_pb2.Empty())
    server.stub.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)))
    observation = TimedObservation(
        timestamp=time.time(), timestep=0, observation={"x": 0.1, "y": -0.2}, must_go=True
    )
    server.stub.SendObservations(send_bytes_in_chunks(pickle.dumps(observation), services_pb2.Observation))
    reply = server.stub.GetActions(services_pb2.Empty())

    assert reply.data, "the server sent no actions; its log:\n" + _log(server.process)
    actions = pickle.loads(reply.data)  # nosec
    assert len(actions) == ACTIONS_PER_CHUNK and all(isinstance(a, TimedAction) for a in actions)
    assert [a.get_timestep() for a in actions] == list(range(ACTIONS_PER_CHUNK))
    for action in actions:
        assert action.get_action().shape == (2,) and torch.isfinite(action.get_action()).all()


def _log(process: subprocess.Popen) -> str:
    process.terminate()
    return process.communicate()[0][-6000:]


def test_lerobots_own_list_refuses_ccdp_until_the_entry_point_adds_it():
    from lerobot.async_inference import policy_server

    supported = supported_policies(policy_server)
    assert supported is policy_server.SUPPORTED_POLICIES
    before = list(supported)
    assert "ccdp" not in before and "diffusion" in before
    try:
        allow_ccdp(policy_server)
        allow_ccdp(policy_server)  # idempotent
        assert supported == [*before, "ccdp"]
    finally:
        supported[:] = before


def test_a_server_without_a_policy_list_is_named_with_the_workaround():
    fake = type(sys)("some.policy_server")
    fake.SUPPORTED = ("act", "diffusion")  # a tuple cannot be extended in place
    with pytest.raises(
        RuntimeError, match=r"some\.policy_server has no list of supported policy types.*from_pretrained"
    ):
        supported_policies(fake)


def test_missing_grpc_names_the_extra_to_install(monkeypatch):
    from lerobot_ccdp.compat.policy_server import lerobot_policy_server

    monkeypatch.setitem(sys.modules, "grpc", None)  # as if LeRobot's async extra were not installed
    monkeypatch.delitem(sys.modules, "lerobot.async_inference.policy_server", raising=False)
    monkeypatch.delattr(lerobot.async_inference, "policy_server", raising=False)  # an earlier import's
    with pytest.raises(
        SystemExit, match=r"needs the 'grpc' package: pip install 'lerobot_policy_ccdp\[async\]'"
    ):
        lerobot_policy_server()
