"""ccdp served by LeRobot's own async-inference policy server through `lerobot-ccdp-policy-server`.

The server runs as its own process (the module the console script calls) on 127.0.0.1 and a free port, one
for the module; the tests talk to it with the gRPC calls LeRobot's robot client makes, in its order: Ready,
SendPolicyInstructions (a pickled RemotePolicyConfig), SendObservations (a pickled TimedObservation in
chunks), GetActions. The checks that need no network run on the entry point's server class in-process.
"""

import json
import pickle  # nosec: LeRobot's async protocol pickles its messages
import re
import shutil
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

from lerobot_ccdp.compat.policy_server import allow_ccdp, checked_server, supported_policies

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


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """The entry point in a subprocess; stopped (by its pid) when the module's tests end."""
    tmp_path = tmp_path_factory.mktemp("policy_server")
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


@pytest.fixture(scope="module")
def checkpoint(reaching_root, tmp_path_factory):
    """An untrained ccdp checkpoint of the 2-D reaching data (state x, y; 8 actions per plan)."""
    out = tmp_path_factory.mktemp("served") / "ckpt"
    return untrained_checkpoint(reaching_root, out, failure_feature="primitive", num_primitives=4)


# What the robot client sends for a robot with two motors x, y (map_robot_keys_to_lerobot_features).
ROBOT = hw_to_dataset_features({"x": float, "y": float}, OBS_STR, use_video=False)


def _setup(stub, checkpoint, actions_per_chunk=ACTIONS_PER_CHUNK, features=ROBOT) -> None:
    specs = RemotePolicyConfig("ccdp", str(checkpoint), features, actions_per_chunk, "cpu")
    stub.Ready(services_pb2.Empty())
    stub.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)))


def _observe(stub, observation: dict, timestep: int = 0) -> None:
    timed = TimedObservation(timestamp=time.time(), timestep=timestep, observation=observation, must_go=True)
    stub.SendObservations(send_bytes_in_chunks(pickle.dumps(timed), services_pb2.Observation))


def test_ccdp_round_trip_through_lerobots_policy_server(server, checkpoint):
    _setup(server.stub, checkpoint)
    _observe(server.stub, {"x": 0.1, "y": -0.2})
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


def test_an_observation_missing_a_robot_key_is_refused_naming_it(server, checkpoint):
    """Before, the server queued it, answered GetActions with nothing and logged only `'y'`."""
    _setup(server.stub, checkpoint)
    with pytest.raises(grpc.RpcError) as refused:
        _observe(server.stub, {"x": 0.1, "z": 0.3}, timestep=1)
    assert (
        "The observation lacks ['y']: the client described the robot with the keys ['x', 'y']"
        in refused.value.details()
    )


def test_zero_actions_per_chunk_is_refused_when_the_policy_is_set_up(server, checkpoint):
    """Before, the setup succeeded and every action chunk came back empty."""
    with pytest.raises(grpc.RpcError) as refused:
        _setup(server.stub, checkpoint, actions_per_chunk=0)
    assert (
        "actions_per_chunk=0: the number of actions the server sends per observation must be an integer "
        ">= 1. Set the robot client's --actions_per_chunk." in refused.value.details()
    )


class _Context:
    def peer(self) -> str:
        return "test-client"


@pytest.fixture
def checked():
    """The entry point's server class, in-process (no network)."""
    from lerobot.async_inference.configs import PolicyServerConfig
    from lerobot.async_inference.policy_server import PolicyServer

    supported = supported_policies(lerobot.async_inference.policy_server)
    before = list(supported)
    allow_ccdp(lerobot.async_inference.policy_server)
    instance = checked_server(PolicyServer)(PolicyServerConfig(host="127.0.0.1", port=1))
    instance.Ready(services_pb2.Empty(), _Context())
    yield instance
    supported[:] = before


def _setup_in_process(server, checkpoint, actions_per_chunk=ACTIONS_PER_CHUNK, features=ROBOT) -> None:
    specs = RemotePolicyConfig("ccdp", str(checkpoint), features, actions_per_chunk, "cpu")
    server.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)), _Context())


def _crafted(checkpoint, tmp_path, **fields):
    """A copy of `checkpoint` whose config.json says `fields`."""
    crafted = shutil.copytree(checkpoint, tmp_path / "crafted")
    config = json.loads((crafted / "config.json").read_text())
    (crafted / "config.json").write_text(json.dumps({**config, **fields}))
    return crafted


@pytest.mark.parametrize(
    "fields,message",
    [
        ({"w_h": -1.0}, r"`w_h` must be >= 0"),
        ({"n_action_steps": 0}, r"n_action_steps"),
    ],
)
def test_a_bad_config_reaching_the_server_is_refused_with_the_configs_message(
    checked, checkpoint, tmp_path, fields, message
):
    crafted = _crafted(checkpoint, tmp_path, **fields)
    with pytest.raises(ValueError, match=rf"The policy at {crafted} cannot be served: .*{message}"):
        _setup_in_process(checked, crafted)
    assert checked.policy is None  # refused before the server changed anything


def test_more_actions_per_chunk_than_the_plan_holds_is_refused_with_the_range(checked, checkpoint):
    with pytest.raises(ValueError, match=r"actions_per_chunk=9: .* plans 8 actions .* can send 1 to 8"):
        _setup_in_process(checked, checkpoint, actions_per_chunk=9)
    assert checked.policy is None


def test_a_robot_whose_state_differs_from_the_checkpoints_is_refused_naming_both(checked, checkpoint):
    robot = hw_to_dataset_features({"x": float, "y": float, "z": float}, OBS_STR, use_video=False)
    with pytest.raises(
        ValueError, match=r"observation.state has shape \(2,\) in the checkpoint and \(3,\) in the robot"
    ):
        _setup_in_process(checked, checkpoint, features=robot)


def test_an_observation_before_the_policy_is_set_up_is_refused(checked):
    observation = TimedObservation(timestamp=time.time(), timestep=0, observation={"x": 0.1}, must_go=True)
    with pytest.raises(ValueError, match=r"before any policy was set up"):
        checked._enqueue_observation(observation)


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


def test_a_ccdp_checkpoint_asked_for_as_another_policy_type_is_refused_with_the_type(checked, checkpoint):
    """Before, LeRobot's diffusion class built itself from the ccdp config and died on a missing field
    ("'CCDPConfig' object has no attribute 'compile_model'")."""
    specs = RemotePolicyConfig("diffusion", str(checkpoint), ROBOT, ACTIONS_PER_CHUNK, "cpu")
    with pytest.raises(ValueError, match=r"is a ccdp checkpoint, but the client asked for policy type "):
        checked.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)), _Context())
    assert checked.policy is None


def test_a_checkpoint_path_that_does_not_exist_is_named_as_such(checked, tmp_path):
    missing = tmp_path / "no_such_checkpoint"
    with pytest.raises(ValueError, match=rf"no file or folder {missing} exists on the server's machine"):
        _setup_in_process(checked, missing)


@pytest.mark.parametrize("value", ["a", [1.0, 2.0], None])
def test_an_observation_value_that_is_not_a_number_is_refused_naming_it(checked, checkpoint, value):
    """Before, numpy's words: "could not convert string to float: 'a'", "setting an array element with a
    sequence"; None became NaN."""
    _setup_in_process(checked, checkpoint)
    observation = TimedObservation(
        timestamp=time.time(), timestep=0, observation={"x": value, "y": 0.2}, must_go=True
    )
    with pytest.raises(ValueError, match=re.escape(f"The observation's { ({'x': value}) } are not numbers")):
        checked._enqueue_observation(observation)


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_a_device_the_server_lacks_is_refused_before_loading(checked, checkpoint):
    """Before, torch's "Found no NVIDIA driver on your system" from LeRobot's policy.to(device)."""
    specs = RemotePolicyConfig("ccdp", str(checkpoint), ROBOT, ACTIONS_PER_CHUNK, "cuda:7")
    with pytest.raises(ValueError, match=r"device='cuda:7' is not available on the server's machine"):
        checked.SendPolicyInstructions(services_pb2.PolicySetup(data=pickle.dumps(specs)), _Context())
    assert checked.policy is None
