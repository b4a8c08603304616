"""Pushing a CCDP policy to the Hub uploads a complete, loadable policy.

The real huggingface_hub client talks to a small in-memory Hub on 127.0.0.1 (tests/fixtures/hub_server.py).
Because huggingface_hub reads HF_ENDPOINT when it is imported, the push and the reload each run in a fresh
subprocess (this file run as a script) with HF_ENDPOINT pointing at the server, HF_HUB_OFFLINE=0, a dummy
token and their own HF_HOME, so the reload really downloads from the server.

Loopback only: the subprocesses install, through huggingface_hub's public `configure_http_backend`, a
requests session that refuses every host but the loopback server. The one hard-coded Hub URL the client
uses, `RepoCard.validate()`'s https://huggingface.co/api/validate-yaml (LeRobot's generate_model_card calls
it), is sent to the loopback server instead.

What is pushed, one commit each, to one repo:
  1. policy.push_to_hub(repo_id)          -> config.json, model.safetensors (LeRobot's HubMixin; no card)
  2. policy.push_model_to_hub(train_cfg)  -> the same + README.md (model card) + train_config.json
                                             (what `lerobot-train --policy.push_to_hub=true` runs)
  3. preprocessor.push_to_hub(repo_id)    -> policy_preprocessor.json + normaliser stats (.safetensors)
  4. postprocessor.push_to_hub(repo_id)   -> policy_postprocessor.json + unnormaliser stats
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO_ID = "test-user/ccdp-reaching2d"
HERE = Path(__file__).resolve()


# ----- the test (pytest side) -------------------------------------------------------------------------


@pytest.fixture
def hub():
    from fixtures.hub_server import HubServer

    server = HubServer().start()
    try:
        yield server
    finally:
        server.stop()


def _client(phase: str, hub, work: Path, home: Path) -> subprocess.CompletedProcess:
    env = {
        **os.environ,
        "HF_ENDPOINT": hub.url,
        "HF_HUB_OFFLINE": "0",
        "HF_TOKEN": "dummy",
        "HF_HOME": str(home),
        "HF_LEROBOT_HOME": str(home / "lerobot"),
        "HF_HUB_DISABLE_TELEMETRY": "1",
        "HF_HUB_ETAG_TIMEOUT": "5",
        "HF_HUB_DOWNLOAD_TIMEOUT": "5",
        "NO_PROXY": "127.0.0.1,localhost",
    }
    result = subprocess.run(
        [sys.executable, str(HERE), phase, REPO_ID, str(work)], env=env, capture_output=True, text=True
    )
    if result.returncode != 0:
        pytest.fail(
            f"{phase} subprocess failed ({result.returncode}):\n"
            f"{result.stdout[-3000:]}\n{result.stderr[-6000:]}"
        )
    return result


def test_push_to_hub_uploads_a_complete_loadable_policy(hub, tmp_path):
    _client("push", hub, tmp_path, tmp_path / "home_push")
    commits = hub.commits(REPO_ID)
    assert len(commits) == 4, [c.summary for c in commits]
    assert [c.summary for c in commits[:2]] == [
        "Upload policy",
        "Upload policy weights, train config and readme",
    ]

    # 1. policy.push_to_hub: config and weights, the weights through LFS as on the real Hub.
    first = commits[0]
    assert sorted(first.changed) == ["config.json", "model.safetensors"]
    assert "model.safetensors" in first.lfs
    config = json.loads(first.files["config.json"])
    assert (
        config["type"] == "ccdp"
        and config["failure_feature"] == "primitive"
        and config["num_primitives"] == 4
    )
    assert len(first.files["model.safetensors"]) > 100_000

    # 2. push_model_to_hub: + model card (validated through the loopback server) and train config.
    second = commits[1]
    assert {"config.json", "model.safetensors", "README.md", "train_config.json"} <= set(second.changed)
    card = second.files["README.md"].decode()
    _check_model_card(card)
    assert any("ccdp" in content for content in hub.validated_yaml)
    assert json.loads(second.files["train_config.json"])["policy"]["type"] == "ccdp"
    assert second.files["model.safetensors"] == first.files["model.safetensors"]

    # 3-4. processors: pipeline configs and their stats files.
    final = hub.files(REPO_ID)
    assert {"policy_preprocessor.json", "policy_postprocessor.json"} <= set(final)
    stats_files = [p for p in final if p.startswith("policy_") and p.endswith(".safetensors")]
    assert len(stats_files) == 2, stats_files
    assert set(commits[2].changed) == {"policy_preprocessor.json", *[p for p in stats_files if "pre" in p]}

    # Reload everything from the server in a fresh process with an empty cache.
    (tmp_path / "commits.json").write_text(json.dumps([c.sha for c in commits]))
    n_requests = len(hub.log)
    _client("reload", hub, tmp_path, tmp_path / "home_reload")
    # Resolved = HEAD (metadata) then GET unless the blob is already cached (the two stats files are
    # identical).
    downloads = [p for m, p in hub.log[n_requests:] if m in ("HEAD", "GET") and "/resolve/" in p]
    assert any(p.endswith("/model.safetensors") for m, p in hub.log[n_requests:] if m == "GET")
    for name in (
        "config.json",
        "model.safetensors",
        "policy_preprocessor.json",
        "policy_postprocessor.json",
        *stats_files,
    ):
        assert any(p.endswith(f"/{name}") for p in downloads), f"{name} was not resolved: {downloads}"
    # The reload of commit 1 (push_to_hub alone) asked for that revision.
    assert any(f"/resolve/{first.sha}/model.safetensors" in p for p in downloads)
    assert all(m != "POST" for m, _ in hub.log[n_requests:]), "the reload must not write"


def _check_model_card(card: str) -> None:
    """The card tells a reader what the policy is, how to install it, train it in two stages and evaluate
    it."""
    assert "library_name: lerobot" in card and "model_name: ccdp" in card and "- ccdp" in card
    assert "local/reaching2d" in card  # the training dataset, in the metadata
    assert "not recognized" not in card
    assert "policy type `ccdp`" in card
    assert "pip install lerobot_policy_ccdp" in card and "pip install -e ." in card
    assert "--policy.type=ccdp" in card  # stage 1: base on demos
    assert "lerobot-ccdp-synthesize" in card and "--policy.training_stage=recovery" in card  # stage 2
    assert f"lerobot-eval --policy.path={REPO_ID} --env.type=ccdp" in card
    assert "--policy.recovery_mode=ccdp" in card and "dp_star" in card
    assert "report_failure()" in card and "--policy.failure_signal_file=" in card  # on a robot
    # This checkpoint as pushed: after both stages, with its failure feature.
    assert "recovery head trained" in card and "failure feature `primitive`" in card


# ----- the client side --------------------------------------------------------------------------------
# (run in a subprocess: python tests/policy/test_hub_push.py push|reload REPO_ID WORK)


def _loopback_only_http_backend() -> None:
    """Route huggingface_hub's HTTP traffic to HF_ENDPOINT only; anything else is refused."""
    from urllib.parse import urlsplit

    import requests
    from huggingface_hub import configure_http_backend

    endpoint = os.environ["HF_ENDPOINT"].rstrip("/")
    allowed = urlsplit(endpoint).netloc

    class LoopbackSession(requests.Session):
        def request(self, method, url, *args, **kwargs):
            parts = urlsplit(url)
            if parts.netloc == "huggingface.co" and parts.path == "/api/validate-yaml":
                url = endpoint + parts.path  # RepoCard.validate() hard-codes the public Hub
            elif parts.netloc != allowed:
                raise requests.ConnectionError(f"test hub: refusing non-loopback request to {url}")
            kwargs["proxies"] = {"http": None, "https": None}
            return super().request(method, url, *args, **kwargs)

    def factory() -> requests.Session:
        session = LoopbackSession()
        session.trust_env = False
        return session

    configure_http_backend(backend_factory=factory)


def _make_policy_and_processors():
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature

    from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
    from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy
    from lerobot_ccdp.policy.processor_ccdp import make_ccdp_pre_post_processors

    torch.manual_seed(123)
    config = CCDPConfig(
        input_features={"observation.state": PolicyFeature(FeatureType.STATE, (2,))},
        output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
        device="cpu",
        failure_feature="primitive",
        num_primitives=4,
        push_to_hub=True,
        repo_id=REPO_ID,
    )
    policy = CCDPPolicy(config)
    # A checkpoint as after both stages: an outcome table (kept in the state dict) and a trained eps_z.
    n, chunk = 50, config.horizon * config.action_dim
    policy.model.outcomes.fill(torch.randn(n, chunk), torch.randn(n, 2), torch.randint(0, 4, (n,)))
    policy.model.recovery_trained.fill_(True)
    stats = {
        "observation.state": {
            "min": torch.tensor([-1.1, -1.2]),
            "max": torch.tensor([1.3, 1.4]),
            "mean": torch.tensor([0.1, 0.2]),
            "std": torch.tensor([0.5, 0.6]),
        },
        "action": {
            "min": torch.tensor([-1.0, -0.9]),
            "max": torch.tensor([1.05, 0.95]),
            "mean": torch.tensor([0.0, 0.1]),
            "std": torch.tensor([0.4, 0.45]),
        },
    }
    preprocessor, postprocessor = make_ccdp_pre_post_processors(config, stats)
    return policy, preprocessor, postprocessor


def _push(repo_id: str, work: Path) -> None:
    from lerobot.configs.default import DatasetConfig
    from lerobot.configs.train import TrainPipelineConfig
    from safetensors.torch import save_file

    policy, preprocessor, postprocessor = _make_policy_and_processors()
    policy.push_to_hub(repo_id)
    policy.push_model_to_hub(
        TrainPipelineConfig(dataset=DatasetConfig(repo_id="local/reaching2d"), policy=policy.config)
    )
    preprocessor.push_to_hub(repo_id)
    postprocessor.push_to_hub(repo_id)
    # References for the reload.
    save_file(
        {k: v.contiguous() for k, v in policy.state_dict().items()}, str(work / "ref_policy.safetensors")
    )
    policy.config.save_pretrained(work / "ref")
    save_file(preprocessor.steps[-1].state_dict(), str(work / "ref_pre.safetensors"))
    save_file(postprocessor.steps[0].state_dict(), str(work / "ref_post.safetensors"))


def _reload(repo_id: str, work: Path) -> None:
    import torch
    from lerobot.processor import PolicyProcessorPipeline
    from lerobot.processor.converters import policy_action_to_transition, transition_to_policy_action
    from safetensors.torch import load_file

    from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

    ref_state = load_file(str(work / "ref_policy.safetensors"))
    ref_config = json.loads((work / "ref" / "config.json").read_text())
    cache = Path(os.environ["HF_HOME"]) / "hub"
    assert not cache.exists() or not any(cache.iterdir()), "the reload must start from an empty cache"

    def check_policy(policy) -> None:
        state = policy.state_dict()
        assert sorted(state) == sorted(ref_state), set(state) ^ set(ref_state)
        for key, value in ref_state.items():
            assert state[key].shape == value.shape and torch.equal(state[key], value), key
        assert bool(policy.model.recovery_trained) and len(policy.model.outcomes) == 50
        policy.config.save_pretrained(work / "reloaded")
        assert json.loads((work / "reloaded" / "config.json").read_text()) == ref_config

    torch.manual_seed(999)  # a different init, so equal weights can only come from the download
    check_policy(CCDPPolicy.from_pretrained(repo_id))
    first_commit = json.loads((work / "commits.json").read_text())[0]
    check_policy(CCDPPolicy.from_pretrained(repo_id, revision=first_commit))
    assert (cache / f"models--{repo_id.replace('/', '--')}").is_dir(), "nothing was downloaded into HF_HOME"

    pre = PolicyProcessorPipeline.from_pretrained(repo_id, config_filename="policy_preprocessor.json")
    post = PolicyProcessorPipeline.from_pretrained(
        repo_id,
        config_filename="policy_postprocessor.json",
        to_transition=policy_action_to_transition,
        to_output=transition_to_policy_action,
    )
    for pipeline, ref_file in ((pre, "ref_pre.safetensors"), (post, "ref_post.safetensors")):
        ref = load_file(str(work / ref_file))
        got = next(s for s in pipeline.steps if hasattr(s, "state_dict") and s.state_dict()).state_dict()
        assert sorted(got) == sorted(ref) and all(torch.equal(got[k], ref[k]) for k in ref), (got, ref)
    assert torch.allclose(pre.steps[-1]._tensor_stats["observation.state"]["max"], torch.tensor([1.3, 1.4]))
    # The reloaded pipelines work end to end with the reloaded policy.
    policy = CCDPPolicy.from_pretrained(repo_id)
    batch = pre({"observation.state": torch.tensor([0.0, 0.0])})
    action = post(policy.select_action(batch))
    assert action.shape == (1, 2) and torch.isfinite(action).all()


if __name__ == "__main__":
    phase, repo, work_dir = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    _loopback_only_http_backend()
    if phase == "push":
        _push(repo, work_dir)
    else:
        _reload(repo, work_dir)
    print(f"{phase}: ok")
