"""draccus reads each config class's source once per process (`lerobot_ccdp/compat/config_help.py`), and the
field help it builds from that source is unchanged."""

import dataclasses
import inspect

import pytest
from draccus.wrappers import docstring
from lerobot.configs.train import TrainPipelineConfig

import lerobot_ccdp  # noqa: F401  (installs the cache, as LeRobot's plugin discovery does)
from lerobot_ccdp.compat.config_help import _SourceOnce, install_source_cache
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig


def _help(config_class: type) -> list:
    return [docstring.get_attribute_docstring(config_class, f.name) for f in dataclasses.fields(config_class)]


def test_importing_the_plugin_installs_the_cache():
    assert isinstance(docstring.inspect, _SourceOnce)


@pytest.mark.parametrize("config_class", [CCDPConfig, TrainPipelineConfig])
def test_the_help_is_unchanged_and_each_class_is_read_once(monkeypatch, config_class):
    monkeypatch.setattr(docstring, "inspect", inspect)
    plain = _help(config_class)
    reads = []

    def counted(obj):
        reads.append(obj)
        return inspect.getsource(obj)

    monkeypatch.setattr(docstring, "inspect", _SourceOnce(counted))
    assert _help(config_class) == plain
    assert any(doc.comment_inline or doc.comment_above or doc.docstring_below for doc in plain)
    # draccus asks once per field; the source is read once per class
    assert len(reads) == len(set(reads)) < len(plain)


def test_a_failed_read_fails_again_the_same_way():
    made = type("MadeAtRunTime", (), {"__module__": __name__})
    cached = _SourceOnce()
    for _ in range(2):
        with pytest.raises(OSError):
            cached.getsource(made)


def test_installed_only_over_inspect_itself_and_once(monkeypatch):
    other = object()
    monkeypatch.setattr(docstring, "inspect", other)
    install_source_cache()
    assert docstring.inspect is other  # someone else's replacement is left alone
    monkeypatch.setattr(docstring, "inspect", inspect)
    install_source_cache()
    first = docstring.inspect
    install_source_cache()
    assert isinstance(first, _SourceOnce) and docstring.inspect is first
