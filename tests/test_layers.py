"""The package's layers run one way (the order in lerobot_ccdp/__init__.py's docstring): every import of every
module, at its top, inside a function or under TYPE_CHECKING, names its own layer or a lower one."""

import ast
from pathlib import Path

import lerobot_ccdp

PACKAGE = Path(lerobot_ccdp.__file__).parent
# Lowest first: what runs at every control step, then the tasks, recording, synthesis and the benchmark.
LAYERS = ("policy", "envs", "datasets", "recovery", "benchmark")
# Beside the layers: LeRobot's patches, each written for the layer it adapts, installed by the package itself.
OUTSIDE = ("compat", "__init__")


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every lerobot_ccdp import in the file, wherever it sits."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            continue
        found += [(node.lineno, name) for name in names if name.split(".")[0] == "lerobot_ccdp"]
    return found


def layer_of(parts: list[str]) -> str:
    """The layer of a module path below lerobot_ccdp (["policy", "heads", "unet"] -> "policy")."""
    return parts[0] if len(parts) > 1 else "__init__"


def upward_imports(package: Path) -> list[str]:
    upward = []
    for path in sorted(package.rglob("*.py")):
        source = layer_of(list(path.relative_to(package).with_suffix("").parts))
        if source in OUTSIDE:
            continue
        for line, module in imported_modules(path):
            target = layer_of(module.split(".")[1:] or ["__init__"])
            if target in OUTSIDE:
                continue
            if LAYERS.index(target) > LAYERS.index(source):
                where = path.relative_to(package.parent)
                upward.append(f"{where}:{line} ({source}) imports {module} ({target})")
    return upward


def test_every_package_is_placed_in_the_layer_order():
    packages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    assert packages == set(LAYERS) | {"compat"}, "place a new package in LAYERS (and the package docstring)"


def test_no_module_imports_a_higher_layer():
    assert upward_imports(PACKAGE) == []


def test_an_upward_import_is_found_wherever_it_sits(tmp_path):
    """The check itself: a policy module that imports synthesis inside a function is reported."""
    (tmp_path / "policy").mkdir()
    (tmp_path / "policy" / "late.py").write_text(
        "def f():\n    from lerobot_ccdp.recovery.synthesize import main\n    return main\n"
    )
    (upward,) = upward_imports(tmp_path)
    assert upward.endswith("policy/late.py:2 (policy) imports lerobot_ccdp.recovery.synthesize (recovery)")
