"""After a plain install, LeRobot's own plugin discovery registers `ccdp` (as its CLIs do, in a fresh
process)."""

import subprocess
import sys

import pytest

CHECK = """
from lerobot.utils.import_utils import register_third_party_plugins
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.factory import get_policy_class, make_pre_post_processors
assert "ccdp" not in PreTrainedConfig.get_known_choices(), "registered before discovery"
register_third_party_plugins()
assert "ccdp" in PreTrainedConfig.get_known_choices()
print(get_policy_class("ccdp").__name__)
"""


def test_plugin_discovery_registers_ccdp_in_a_fresh_process():
    result = subprocess.run([sys.executable, "-c", CHECK], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().endswith("CCDPPolicy")


# A process start (about 20 s on the slower machine); lerobot-train --policy.type=ccdp runs in
# tests/fixtures/reaching.py.
@pytest.mark.slow
def test_lerobot_train_parses_policy_type_ccdp():
    from fixtures.reaching import BIN

    result = subprocess.run(
        [str(BIN / "lerobot-train"), "--policy.type=ccdp", "--help"], capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr
    assert "--policy.w_z" in result.stdout and "--policy.recovery_mode" in result.stdout
