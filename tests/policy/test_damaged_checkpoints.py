"""A missing, damaged or untrusted checkpoint folder is refused with its path and the fix, before LeRobot
reads it: through CCDPPolicy.from_pretrained (also what lerobot-eval and lerobot-record call) and
lerobot-ccdp-synthesize."""

import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from lerobot.processor import ProcessorStep, ProcessorStepRegistry

from lerobot_ccdp.datasets.recipe_file import RecoveryRecipe
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.recovery.synthesize import synthesize_recovery_dataset

from fixtures.reaching import REACHING_REPO_ID

DAMAGED = "is damaged .*Re-train the checkpoint, or copy or download it again"


def damaged_copy(checkpoint: Path, tmp_path: Path, damage: Callable[[Path], None]) -> Path:
    copy = tmp_path / "pretrained_model"
    shutil.copytree(checkpoint, copy)
    damage(copy)
    return copy


def truncate_weights(folder: Path) -> None:
    weights = folder / "model.safetensors"
    weights.write_bytes(weights.read_bytes()[: weights.stat().st_size // 2])


def garble_config(folder: Path) -> None:
    (folder / "config.json").write_text('{"type": "ccdp", "horizon": 1')


def synthesize_from(policy_path: Path | str, demo_root: Path, out_root: Path) -> None:
    recipe = RecoveryRecipe.from_dict({"n_states": 4, "chunks_per_state": 2})
    synthesize_recovery_dataset(
        recipe, REACHING_REPO_ID, demo_root, policy_path, "local/r", out_root, progress=False
    )


@pytest.mark.parametrize(
    ("damage", "file"), [(truncate_weights, "model.safetensors"), (garble_config, "config.json")]
)
def test_a_damaged_checkpoint_file_is_named_with_the_fix(
    untrained_primitive_checkpoint, reaching_root, tmp_path, damage, file
):
    folder = damaged_copy(untrained_primitive_checkpoint, tmp_path, damage)
    message = f"Checkpoint file {folder / file} {DAMAGED}"
    with pytest.raises(ValueError, match=message):
        CCDPPolicy.from_pretrained(folder)
    with pytest.raises(ValueError, match=message):
        synthesize_from(folder, reaching_root, tmp_path / "recovery")
    assert not (tmp_path / "recovery").exists()


@pytest.mark.parametrize("missing", ["does/not/exist", "outputs/base"])
def test_a_missing_checkpoint_folder_is_named_not_taken_for_a_repo_id(reaching_root, tmp_path, missing):
    """`outputs/base` has a repo id's form: the Hub is asked (offline here), then the missing folder is
    named."""
    message = f"Checkpoint folder {missing} does not exist .*checkpoints/last/pretrained_model"
    with pytest.raises(FileNotFoundError, match=message):
        CCDPPolicy.from_pretrained(missing)
    with pytest.raises(FileNotFoundError, match=message):
        synthesize_from(missing, reaching_root, tmp_path / "recovery")


def test_a_folder_that_is_no_checkpoint_is_named(reaching_root):
    with pytest.raises(
        FileNotFoundError, match=f"{reaching_root} holds no config.json, so it is not a policy"
    ):
        CCDPPolicy.from_pretrained(reaching_root)


def test_a_missing_demo_folder_says_it_does_not_exist(untrained_primitive_checkpoint, tmp_path):
    with pytest.raises(
        FileNotFoundError, match=f"--dataset.root={tmp_path / 'demos'}: the folder does not exist"
    ):
        synthesize_from(untrained_primitive_checkpoint, tmp_path / "demos", tmp_path / "recovery")


class ForeignStep(ProcessorStep):
    """A step registered by a package other than LeRobot and lerobot_ccdp."""


@pytest.fixture
def foreign_registry_name():
    ProcessorStepRegistry.register("ccdp_test_foreign_step")(ForeignStep)
    yield "ccdp_test_foreign_step"
    ProcessorStepRegistry.unregister("ccdp_test_foreign_step")


@pytest.mark.parametrize("entry", ["os.system", "lerobot_ccdp.policy.checkpoint_files.importlib", "foreign"])
def test_a_processor_step_from_outside_lerobot_and_ccdp_is_refused_before_it_runs(
    untrained_primitive_checkpoint, reaching_root, tmp_path, foreign_registry_name, entry
):
    """Checkpoints are code: LeRobot's loader would import and call the class a processor file names."""
    marker = tmp_path / "ran"
    step = (
        {"registry_name": foreign_registry_name}
        if entry == "foreign"
        else {"class": entry, "config": {"command": f"touch {marker}"}}
    )

    def add_step(folder: Path) -> None:
        processor = folder / "policy_preprocessor.json"
        content = json.loads(processor.read_text())
        content["steps"].insert(1, step)
        processor.write_text(json.dumps(content))

    folder = damaged_copy(untrained_primitive_checkpoint, tmp_path, add_step)
    name = foreign_registry_name if entry == "foreign" else entry
    message = (
        f"{folder / 'policy_preprocessor.json'}: step 1 names '{name}', which is not a processor step of "
        "LeRobot or lerobot_ccdp.*Checkpoints are code: load only ones you trust"
    )
    with pytest.raises(ValueError, match=message):
        CCDPPolicy.from_pretrained(folder)
    with pytest.raises(ValueError, match=message):
        synthesize_from(folder, reaching_root, tmp_path / "recovery")
    assert not marker.exists()


def test_processor_steps_named_by_lerobot_class_path_are_accepted(untrained_primitive_checkpoint, tmp_path):
    """LeRobot writes `class` (a module path) for unregistered steps; its own and ours load as before."""

    def spell_out_classes(folder: Path) -> None:
        processor = folder / "policy_preprocessor.json"
        content = json.loads(processor.read_text())
        for entry in content["steps"]:
            step = ProcessorStepRegistry.get(entry.pop("registry_name"))
            entry["class"] = f"{step.__module__}.{step.__name__}"
        processor.write_text(json.dumps(content))

    assert (
        CCDPPolicy.from_pretrained(damaged_copy(untrained_primitive_checkpoint, tmp_path, spell_out_classes))
        is not None
    )


# ----- issue 110, second round: what LeRobot's loaders take as they are ------------------------------------


def _edit_tensors(file: Path, edit: Callable[[dict], dict]) -> None:
    from safetensors.torch import load_file, save_file

    save_file(edit(load_file(file)), file)


POST_STATS = "policy_postprocessor_step_0_unnormalizer_processor.safetensors"
PRE_STATS = "policy_preprocessor_step_3_normalizer_processor.safetensors"


@pytest.mark.parametrize(
    ("file", "edit", "named"),
    [
        (POST_STATS, lambda s: {**s, "action.max": s["action.max"] * float("nan")}, "action.max holds NaN"),
        (
            PRE_STATS,
            lambda s: {**s, "observation.state.max": s["observation.state.min"] - 1},
            "observation.state.max < observation.state.min",
        ),
    ],
)
def test_a_processors_wrong_stats_are_refused_at_load(
    untrained_primitive_checkpoint, tmp_path, file, edit, named
):
    """Before: NaN unnormaliser stats loaded, and the README's robot loop returned NaN actions; a max below
    its min mirrored every input. LeRobot loads the processors' stats as they are."""
    copy = damaged_copy(untrained_primitive_checkpoint, tmp_path, lambda f: _edit_tensors(f / file, edit))
    with pytest.raises(ValueError, match=rf"{file} is damaged .*{named}"):
        CCDPPolicy.from_pretrained(copy)


@pytest.mark.parametrize(
    ("edit", "named"),
    [
        (lambda t: t.to(torch.int32), r"holds I32, not floats"),
        (lambda t: torch.zeros(3, 3), r"has shape \(3, 3\), the config makes \(128, 32\)"),
    ],
)
def test_weights_of_another_dtype_or_shape_are_named_before_they_are_copied(
    untrained_primitive_checkpoint, tmp_path, edit, named
):
    """Before: integer weights were copied truncated into the float networks, without a word; a wrong shape
    gave torch's size-mismatch list."""
    key = "model.base.unet.diffusion_step_encoder.1.weight"
    copy = damaged_copy(
        untrained_primitive_checkpoint,
        tmp_path,
        lambda f: _edit_tensors(f / "model.safetensors", lambda s: {**s, key: edit(s[key])}),
    )
    with pytest.raises(
        ValueError, match=rf"do not fit the ccdp policy.*{re.escape(key)} {named}.*config.json"
    ):
        CCDPPolicy.from_pretrained(copy)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"w_z": True}, r'says "w_z": true; it takes a number'),
        ({"horizon": "16"}, r'says "horizon": "16"; it takes a whole number'),
        ({"input_features": None}, r"is damaged \(it has no input_features\)"),
    ],
)
def test_a_config_json_with_mistyped_or_missing_entries_is_named(
    untrained_primitive_checkpoint, tmp_path, fields, message
):
    """Before: draccus read "w_z": true as 1.0 and "horizon": "16" as 16 without a word, and a config.json
    without input_features was reported as a dataset without observation.state."""

    def edit(folder: Path) -> None:
        config = json.loads((folder / "config.json").read_text())
        config.update(fields)
        (folder / "config.json").write_text(json.dumps({k: v for k, v in config.items() if v is not None}))

    with pytest.raises(ValueError, match=message):
        CCDPPolicy.from_pretrained(damaged_copy(untrained_primitive_checkpoint, tmp_path, edit))


def test_a_checkpoint_without_weights_or_named_by_none_is_named_with_the_fix(
    untrained_primitive_checkpoint, tmp_path
):
    """Before: torch's bare "No such file or directory: .../model.safetensors", and pathlib's "expected str,
    bytes or os.PathLike object, not NoneType"."""
    copy = damaged_copy(
        untrained_primitive_checkpoint, tmp_path, lambda f: (f / "model.safetensors").unlink()
    )
    with pytest.raises(FileNotFoundError, match=r"holds config.json but no model.safetensors: .*incomplete"):
        CCDPPolicy.from_pretrained(copy)
    with pytest.raises(
        TypeError, match=r"named by a str or Path; got None. Pass the pretrained_model folder"
    ):
        CCDPPolicy.from_pretrained(None)


@pytest.mark.parametrize(
    ("edit", "named"),
    [
        (lambda s: {**s, "model.outcomes.chunks": s["model.outcomes.chunks"][:, :7]}, r"chunks \(\d+, 7\)"),
        (
            lambda s: {**s, "model.outcomes.primitives": s["model.outcomes.primitives"] * 0 + 99},
            "labels 99..99",
        ),
    ],
)
def test_an_outcome_table_the_config_does_not_make_is_refused_at_load(
    untrained_primitive_checkpoint, tmp_path, edit, named
):
    """Before: it loaded, and DP* died after the first failure in torch ("X1 and X2 must have the same number
    of columns", "Class values must be smaller than num_classes")."""
    copy = damaged_copy(
        untrained_primitive_checkpoint,
        tmp_path,
        lambda f: _edit_tensors(
            f / "model.safetensors", lambda s: {k: v.contiguous() for k, v in edit(s).items()}
        ),
    )
    with pytest.raises(ValueError, match=rf"outcome table in .* does not fit the policy.*{named}.*altered"):
        CCDPPolicy.from_pretrained(copy)
