"""Checks on a local checkpoint folder before LeRobot reads it.

Without them a wrong path surfaces as a Hub repo-id error, a damaged file as a bare JSON or safetensors error
that names no file, and a processor file naming any class makes LeRobot's processor loader import and run it.
Here each gives an error naming the path and the fix. A Hub repo id is left to LeRobot's own download.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import logging
import os
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import fields
from importlib.resources import files
from pathlib import Path
from typing import Any

import torch
from huggingface_hub import ModelCard, ModelCardData, hf_hub_download
from huggingface_hub.constants import SAFETENSORS_SINGLE_FILE
from huggingface_hub.errors import HFValidationError
from huggingface_hub.utils import validate_repo_id
from lerobot.configs.parser import get_cli_overrides
from lerobot.configs.policies import PreTrainedConfig
from lerobot.processor import ProcessorStep, ProcessorStepRegistry
from lerobot.utils.constants import (
    OBS_ENV_STATE,
    OBS_STATE,
    POLICY_POSTPROCESSOR_DEFAULT_NAME,
    POLICY_PREPROCESSOR_DEFAULT_NAME,
)
from safetensors import SafetensorError, safe_open
from safetensors.torch import load_file

from lerobot_ccdp.policy.config_checks import refuse_mistyped_json
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.observations import vector_keys

logger = logging.getLogger(__name__)

CONFIG_FILE = "config.json"
PROCESSOR_FILES = (f"{POLICY_PREPROCESSOR_DEFAULT_NAME}.json", f"{POLICY_POSTPROCESSOR_DEFAULT_NAME}.json")
TRUSTED_PACKAGES = ("lerobot", "lerobot_ccdp")
WHERE = (
    "pass the pretrained_model folder lerobot-train wrote (<output_dir>/checkpoints/last/pretrained_model)"
)
# Settings CCDPConfig no longer has (issue 112), each with the value at which the policy sampled as it now
# always does, and what it now does. A saved config.json holding one at that value loads without it.
RETIRED_FIELDS: dict[str, tuple[Any, str]] = {
    "w_s": (1.0, "eq. (4)'s state weight is 1"),
    "w_z_from_step": (0, "w_z applies on the noisiest `w_z_steps` reverse steps"),
    "z_reference": ("eps_z_null", "the failure terms are measured against eps_z_null"),
    "failure_state_key": (OBS_STATE, "`failure_state_dims` index the state frame"),
    "failure_action_steps": ([], "an `action` z is the whole chunk"),
    "failure_action_dims": ([], "an `action` z is the whole chunk"),
    "ccdp_redraws": (0, "CCDP draws one sample per plan"),
}


@contextlib.contextmanager
def checkpoint_loading(path: str | Path) -> Iterator[None]:
    """Check the checkpoint at `path` (`check_checkpoint`), then run the block that loads it; a name that is
    no local folder and that the Hub did not resolve either is reported as the missing folder it most likely
    is."""
    check_checkpoint(path)
    try:
        yield
    except FileNotFoundError as error:
        if Path(path).is_dir():
            raise
        raise FileNotFoundError(_missing(path, str(error))) from error


def check_checkpoint(path: str | Path) -> None:
    """Refuse a local checkpoint folder that is missing, not a checkpoint, damaged, or that names a processor
    step from outside LeRobot and this package. A name that is no folder but may be a Hub repo id passes."""
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(
            f"The checkpoint is named by a str or Path; got {path!r}. {WHERE[0].upper()}{WHERE[1:]}."
        )
    folder = Path(path)
    if not folder.is_dir():
        _refuse_unless_repo_id(path)
        return
    if not (folder / CONFIG_FILE).is_file():
        raise FileNotFoundError(
            f"{folder} holds no {CONFIG_FILE}, so it is not a policy checkpoint; {WHERE}."
        )
    config = _read_json(folder / CONFIG_FILE)
    if not isinstance(config, dict) or "type" not in config:
        raise _damaged(folder / CONFIG_FILE, "it has no policy 'type' entry")
    mixed = mixed_config_error(folder)
    if mixed is not None:
        raise mixed
    if config["type"] == CCDPConfig.get_choice_name(CCDPConfig):
        lacking = [k for k in ("input_features", "output_features") if not isinstance(config.get(k), dict)]
        if lacking:
            raise _damaged(folder / CONFIG_FILE, f"it has no {' or '.join(lacking)}")
        refuse_mistyped_json(config, str(folder / CONFIG_FILE))
    if (
        config["type"] == CCDPConfig.get_choice_name(CCDPConfig)
        and not (folder / SAFETENSORS_SINGLE_FILE).is_file()
    ):
        raise FileNotFoundError(
            f"{folder} holds {CONFIG_FILE} but no {SAFETENSORS_SINGLE_FILE}: the checkpoint is incomplete (a "
            "copy or download that stopped early, or a file removed). Copy or download it again, or use "
            "another checkpoint (<output_dir>/checkpoints/<step>/pretrained_model)."
        )
    for file in sorted(folder.glob("*.safetensors")):
        _check_safetensors(file)
    for name in PROCESSOR_FILES:
        if (folder / name).is_file():
            check_processor_steps(folder / name)
            check_processor_stats(folder / name)


def mixed_config_error(folder: str | Path) -> ValueError | None:
    """The error for a local checkpoint whose config.json's "type" names another policy than its fields
    describe, one of the two being ccdp (None otherwise): draccus would list every field the named type lacks
    (40 for a ccdp config that says "diffusion") without saying why. Other mixes are left to LeRobot."""
    file = Path(folder) / CONFIG_FILE
    content = _read_json(file) if file.is_file() else None
    if not isinstance(content, dict) or not isinstance(content.get("type"), str):
        return None
    kind, keys = content["type"], set(content) - {"type"}
    known = PreTrainedConfig.get_known_choices()

    def fields_of(name: str) -> set[str]:
        return {f.name for f in fields(known[name])} if name in known else set()

    owner = next((name for name in ["ccdp", *known] if keys <= fields_of(name)), None)
    if kind == owner or keys <= fields_of(kind) or owner is None or "ccdp" not in (kind, owner):
        return None
    foreign = sorted(keys - fields_of(kind))
    lacks = (
        f" (a {kind!r} config has no {', '.join(foreign[:3])}{', ...' if len(foreign) > 3 else ''})"
        if kind in known
        else f" ({kind!r} is no policy type LeRobot knows)"
    )
    return ValueError(
        f'{file} says "type": {json.dumps(kind)}, but its fields are those of a {owner!r} policy config'
        f'{lacks}. If the file was edited, set "type": "{owner}" again; otherwise load it as the '
        f"{owner!r} checkpoint it is."
    )


def check_processor_steps(file: Path) -> None:
    """Refuse a processor file any of whose steps is not a ProcessorStep class of LeRobot or lerobot_ccdp.

    LeRobot's processor loader imports and instantiates whatever class a step names, so a crafted checkpoint
    could run any code. The names are resolved here without importing anything outside those two packages."""
    content = _read_json(file)
    steps = content.get("steps") if isinstance(content, dict) else None
    if not isinstance(steps, list):
        raise _damaged(file, "it has no list of 'steps'")
    for index, entry in enumerate(steps):
        if not _trusted_step(entry):
            raise ValueError(
                f"{file}: step {index} names {_step_name(entry)!r}, which is not a processor step of LeRobot "
                "or lerobot_ccdp. LeRobot would import and run that class when loading the checkpoint, so it "
                "was refused and nothing from it ran. Checkpoints are code: load only ones you trust."
            )


# Per normalisation entry, the pairs of stats (low, high) whose order is fixed, and those that are >= 0.
ORDERED_STATS = (("min", "max"), ("q01", "q99"), ("q10", "q90"))
NON_NEGATIVE_STATS = ("std",)


def check_processor_stats(file: Path) -> None:
    """Refuse a processor's saved stats of the features it (un)normalises that are non-finite or out of
    order (a max below its min, a negative std): LeRobot loads them as they are, and NaN unnormaliser stats
    made every action NaN, an inverted range mirrored every input, with no error."""
    for entry in _read_json(file)["steps"]:
        state_file = entry.get("state_file") if isinstance(entry, dict) else None
        features = (entry.get("config") or {}).get("features") if state_file else None
        if not isinstance(features, dict) or not (file.parent / state_file).is_file():
            continue
        stats = load_file(file.parent / state_file)
        used = {k: v for k, v in stats.items() if k.rpartition(".")[0] in features}
        wrong = [f"{k} holds NaN or inf" for k, v in used.items() if not bool(torch.isfinite(v).all())]
        wrong += [
            f"{key}.{high} < {key}.{low}"
            for key in features
            for low, high in ORDERED_STATS
            if f"{key}.{low}" in used
            and f"{key}.{high}" in used
            and bool((used[f"{key}.{high}"] < used[f"{key}.{low}"]).any())
        ]
        wrong += [
            f"{k} < 0"
            for k, v in used.items()
            if k.rpartition(".")[2] in NON_NEGATIVE_STATS and (v < 0).any()
        ]
        if wrong:
            raise _damaged(
                file.parent / state_file,
                f"its normalisation stats are wrong: {'; '.join(wrong[:3])}{'; ...' * (len(wrong) > 3)}; "
                "inputs or actions passed through them would be NaN or mirrored",
            )


def _trusted_step(entry: Any) -> bool:
    step = _step_class(entry) if isinstance(entry, dict) else None
    return isinstance(step, type) and issubclass(step, ProcessorStep) and _in_trusted_package(step.__module__)


def _step_class(entry: dict) -> object | None:
    """What the entry's `registry_name` (LeRobot's registry) or `class` (a module path) names, or None. A
    module path is imported only inside the trusted packages."""
    if "registry_name" in entry:
        try:
            return ProcessorStepRegistry.get(entry["registry_name"])
        except (KeyError, TypeError):
            return None
    module_name, _, name = str(entry.get("class", "")).rpartition(".")
    if not _in_trusted_package(module_name):
        return None
    try:
        return getattr(importlib.import_module(module_name), name, None)
    except ImportError:
        return None


def _step_name(entry: Any) -> str:
    if isinstance(entry, dict):
        return str(entry.get("registry_name", entry.get("class", entry)))
    return str(entry)


def _in_trusted_package(module: str) -> bool:
    return any(module == package or module.startswith(f"{package}.") for package in TRUSTED_PACKAGES)


def _refuse_unless_repo_id(path: str | Path) -> None:
    missing = missing_checkpoint(path)
    if missing is not None:
        raise missing


def missing_checkpoint(path: object) -> OSError | None:
    """The error naming `path` as a checkpoint folder that is not there (a file, or neither a folder nor a
    Hub repo id), or None where it may be a checkpoint."""
    if not isinstance(path, (str, os.PathLike)) or Path(path).is_dir():
        return None
    if Path(path).exists():
        return NotADirectoryError(f"Checkpoint {path} is a file, not a folder; {WHERE}.")
    try:
        validate_repo_id(str(path))
    except HFValidationError:
        return FileNotFoundError(_missing(path, "nor is it a Hub repo id"))
    return None


def _missing(path: str | Path, detail: str) -> str:
    return f"Checkpoint folder {path} does not exist ({detail}): check the path, or {WHERE}."


def _read_json(file: Path) -> Any:
    try:
        return json.loads(file.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise _damaged(file, f"not valid JSON: {error}") from None


def _check_safetensors(file: Path) -> None:
    """Opening reads the header and checks the file's length against it, so a truncated file fails here."""
    try:
        with safe_open(file, framework="pt"):
            pass
    except SafetensorError as error:
        raise _damaged(file, str(error)) from None


def _damaged(file: Path, what: str) -> ValueError:
    return ValueError(
        f"Checkpoint file {file} is damaged ({what}). Re-train the checkpoint, or copy or download it again."
    )


HUB_DOWNLOAD_KEYS = (
    "force_download",
    "resume_download",
    "proxies",
    "token",
    "cache_dir",
    "local_files_only",
    "revision",
)


def saved_config(path: str | Path, **hub: Any) -> dict:
    """The checkpoint's config.json as saved, before any command-line override: from the local folder, or the
    Hub file LeRobot has just downloaded for the same checkpoint (cached)."""
    return _read_json(_checkpoint_file(path, CONFIG_FILE, **hub))


@contextlib.contextmanager
def current_layout(path: str | Path, **hub: Any) -> Iterator[str | Path]:
    """`path`, or for a ccdp checkpoint whose config.json holds `RETIRED_FIELDS` a folder holding its
    config.json without them (`without_retired_fields`), for LeRobot's `PreTrainedConfig.from_pretrained`,
    which refuses a field the config class lacks. A file that cannot be read is left to LeRobot's error."""
    try:
        saved = saved_config(path, **hub)
    except Exception:  # noqa: BLE001 (LeRobot's own read names the problem)
        saved = None
    if not isinstance(saved, dict) or saved.get("type") != CCDPConfig.get_choice_name(CCDPConfig):
        yield path
        return
    current = without_retired_fields(saved, f"{path}/{CONFIG_FILE}")
    if current is saved:
        yield path
        return
    with tempfile.TemporaryDirectory() as folder:
        (Path(folder) / CONFIG_FILE).write_text(json.dumps(current))
        yield folder


def without_retired_fields(saved: dict, file: str) -> dict:
    """A ccdp config.json's content without the `RETIRED_FIELDS` it holds at the values the policy now fixes
    (one log line names them), with `failure_state_key` = environment state turned into the same dims of the
    state frame; `saved` itself when it holds none. A retired field at another value is refused: the
    checkpoint would sample otherwise than it was evaluated."""
    retired = {name: saved[name] for name in RETIRED_FIELDS if name in saved}
    if not retired:
        return saved
    current = {name: value for name, value in saved.items() if name not in retired}
    if retired.get("failure_state_key") == OBS_ENV_STATE:
        features = saved.get("input_features", {})
        robot, env = (features.get(key, {}).get("shape", [0])[0] for key in (OBS_STATE, OBS_ENV_STATE))
        current["failure_state_dims"] = [robot + d for d in saved.get("failure_state_dims") or range(env)]
        retired["failure_state_key"] = OBS_STATE
    changed = {name: value for name, value in retired.items() if value != RETIRED_FIELDS[name][0]}
    if changed:
        raise ValueError(
            f"{file} sets "
            + "; ".join(
                f"{name}={json.dumps(value)}, which CCDP no longer offers ({RETIRED_FIELDS[name][1]})"
                for name, value in changed.items()
            )
            + ". Evaluate the checkpoint with the lerobot_ccdp release that trained it, or remove "
            f"{', '.join(changed)} from its config.json to load it as the policy now samples."
        )
    logger.warning(
        f"{file}: dropped the retired setting(s) {', '.join(retired)}, at the values the policy now fixes."
    )
    return current


def _checkpoint_file(path: str | Path, filename: str, **hub: Any) -> Path:
    """`filename` of the checkpoint: in the local folder, or the Hub file LeRobot has just downloaded
    (cached)."""
    folder = Path(path)
    return (
        folder / filename
        if folder.is_dir()
        else Path(hf_hub_download(repo_id=str(path), filename=filename, **hub))
    )


def refuse_other_checkpoint(config: Any, saved: dict, path: str | Path) -> None:
    """Refuse a checkpoint of another policy type, or one whose action size differs from the dataset's or
    env's (LeRobot sets the output features from them), naming both layouts instead of a state-dict size
    mismatch."""
    if saved.get("type") == CCDPConfig.get_choice_name(CCDPConfig) and not (
        isinstance(config, CCDPConfig) and config.input_features and config.output_features
    ):
        what = (
            f"a {type(config).__name__}"
            if not isinstance(config, CCDPConfig)
            else "a CCDPConfig without features"
        )
        raise ValueError(
            f"{path} is a ccdp checkpoint, and the config given to load it is {what}. Pass the "
            "checkpoint's own config, edited as needed: config = PreTrainedConfig.from_pretrained(path); "
            "config.<field> = ...; CCDPPolicy.from_pretrained(path, config=config)."
        )
    if not isinstance(config, CCDPConfig):
        raise ValueError(
            f"{path} is a {saved.get('type')!r} checkpoint, not a ccdp one. Load it with its own policy "
            f"class (--policy.type={saved.get('type')}), or pass a checkpoint trained with "
            "--policy.type=ccdp."
        )
    saved_action = _layout(saved.get("output_features", {})).get("action")
    given = config.output_features.get("action")
    if saved_action is None or given is None or saved_action[-1:] == tuple(given.shape)[-1:]:
        _refuse_other_frame(config, path)
        return
    raise ValueError(
        f"{path} was trained for another task or robot: it takes inputs "
        f"{_layout(saved.get('input_features', {}))} and acts with action {saved_action}, but the dataset or "
        f"env given has action {tuple(given.shape)} (inputs "
        f"{_layout({k: {'shape': v.shape} for k, v in config.input_features.items()})}). Use a checkpoint "
        "trained on this task, or the dataset or env it was trained on."
    )


# A buffer sized by a frame's vector inputs (`observations.ConstantInputs`): the frame the weights learnt.
FRAME_BUFFER = "model.constant_inputs.value"


def _refuse_other_frame(config: CCDPConfig, path: str | Path) -> None:
    """Refuse a local checkpoint whose weights were trained on another frame size than the vector inputs the
    config names (config.json's `input_features` edited, or the caller's config), naming each feature and
    both sizes instead of LeRobot's state-dict size mismatch. A checkpoint saved before that buffer existed is
    left to the load."""
    weights = Path(path) / SAFETENSORS_SINGLE_FILE
    keys = [key for key in vector_keys(config) if key in config.input_features]
    if not weights.is_file() or len(keys) != len(vector_keys(config)):
        return
    with safe_open(weights, framework="pt") as saved:
        if FRAME_BUFFER not in set(saved.keys()):
            return
        trained = saved.get_slice(FRAME_BUFFER).get_shape()[0]
    shapes = {key: tuple(config.input_features[key].shape) for key in keys}
    if sum(shape[0] for shape in shapes.values()) == trained:
        return
    named = " + ".join(f"{key} {shape}" for key, shape in shapes.items())
    raise ValueError(
        f"The policy is to read {named}, {sum(s[0] for s in shapes.values())} values per frame, but the "
        f"weights in {path} were trained on {trained} ({FRAME_BUFFER}). If its config.json's input_features "
        "were edited, restore the shapes lerobot-train saved; otherwise use a checkpoint trained on this "
        "dataset, env or robot."
    )


def _layout(features: dict) -> dict[str, tuple]:
    return {key: tuple(value.get("shape", ())) for key, value in features.items() if isinstance(value, dict)}


def ignore_saved_signal_file(config: Any, saved: dict) -> None:
    """A checkpoint never chooses the file the policy watches for failures (`failure_signal_file`): that comes
    from the command line (`--policy.failure_signal_file`) or the caller's config. A value that only the
    checkpoint's config.json holds is dropped, with a warning; checkpoints this package saves hold none."""
    named = saved.get("failure_signal_file")
    if named is None or config.failure_signal_file != named or _named_on_command_line(named):
        return
    logger.warning(
        "The checkpoint's config names failure_signal_file=%r; a checkpoint cannot choose a file for the "
        "policy to watch, so it is ignored. Pass --policy.failure_signal_file to use one.",
        named,
    )
    config.failure_signal_file = None


def _named_on_command_line(value: str) -> bool:
    overrides = get_cli_overrides("policy") or []
    return f"--failure_signal_file={value}" in overrides


# The set denoiser's guard (`heads.set_denoiser.FailureSetDenoiser.guard`) and its `guard_trained` flag.
GUARD_PREFIX = "model.recovery.guard"
# Whether the recovery stage has trained the checkpoint's head (`CCDPModel.recovery_trained`).
RECOVERY_TRAINED = "model.recovery_trained"


def refuse_unfit_weights(state: dict, recovery_trained: bool, path: str | Path, **hub: Any) -> None:
    """Refuse a checkpoint whose saved weights do not match the policy's `state` dict. LeRobot loads
    non-strictly and would leave such weights at their random start. Only an untrained recovery head may
    differ: a base checkpoint can start the recovery stage with another head (`--policy.recovery_head`); and a
    set denoiser saved before its guard existed loads without one."""
    with safe_open(_checkpoint_file(path, SAFETENSORS_SINGLE_FILE, **hub), framework="pt") as saved:
        saved_keys = set(saved.keys())
    missing, unexpected = sorted(set(state) - saved_keys), sorted(saved_keys - set(state))
    if not recovery_trained:
        missing, unexpected = (
            [k for k in keys if not k.startswith("model.recovery.")] for keys in (missing, unexpected)
        )
    if not any(k.startswith(GUARD_PREFIX) for k in saved_keys):
        # A set denoiser saved before its guard existed: the guard stays untrained (`guard_trained` False)
        # and sampling refuses `failure_guard_steps` > 0 with the fix.
        missing = [k for k in missing if not k.startswith(GUARD_PREFIX)]
    refuse_non_finite_weights(state, path)
    if missing or unexpected:
        raise ValueError(
            f"The weights in {path} do not fit the ccdp policy its config describes: "
            f"{_listed(missing, 'missing')}, {_listed(unexpected, 'unexpected')}. A checkpoint saved before "
            "the networks moved under `model.` (lerobot_ccdp before the policy/model split) or with other "
            "network settings cannot be loaded: retrain it, or load it with the lerobot_ccdp version that "
            "saved it."
        )


OUTCOMES = "model.outcomes."


def refuse_unfit_outcome_table(state: dict, config: CCDPConfig, path: str | Path) -> None:
    """Refuse a loaded outcome table (`model.outcomes.*`, sized by the saved file) whose layout the config
    does not make: chunks of another length, final states of another width, rows that differ in number, or
    primitive labels outside 0..num_primitives-1. DP* and the failure features read it only after the first
    failure, and died there in torch ("X1 and X2 must have the same number of columns", "Class values must
    be smaller than num_classes")."""
    chunks, finals, labels = (state[f"{OUTCOMES}{name}"] for name in ("chunks", "final_states", "primitives"))
    if chunks.shape[0] == 0:
        return  # no table: a failure feature that needs none, or a checkpoint that names the need when used
    source = config.robot_state_feature
    width = len(config.failure_state_dims) or (source.shape[0] if source is not None else finals.shape[-1])
    wrong = [
        f"{what} {tuple(tensor.shape)}, the config makes ({chunks.shape[0]}, {size})"
        for what, tensor, size in (
            ("chunks", chunks, config.horizon * config.action_dim),
            ("final_states", finals, width),
        )
        if tuple(tensor.shape) != (chunks.shape[0], size)
    ]
    if labels.shape != (chunks.shape[0],):
        wrong.append(f"primitives {tuple(labels.shape)} for {chunks.shape[0]} chunks")
    elif config.failure_feature == "primitive" and not bool(
        ((labels >= 0) & (labels < config.num_primitives)).all()
    ):
        wrong.append(
            f"primitive labels {labels.min().item()}..{labels.max().item()}, "
            f"not 0..{config.num_primitives - 1}"
        )
    if wrong:
        raise ValueError(
            f"The outcome table in {path} does not fit the policy its config describes: {'; '.join(wrong)}. "
            "lerobot-train builds it from the dataset with the checkpoint's settings, so the weights file or "
            "config.json was altered: train again, or copy or download the checkpoint again."
        )


def refuse_unloadable_weights(state: dict, file: str | Path) -> list[str]:
    """Before the weights in `file` are copied into the policy's `state`: refuse tensors whose shape differs
    (torch lists size mismatches without the cause) and floating weights saved as integers (torch copies
    the truncated values without a word, and the policy acts on them). Returns the saved tensors to leave
    out: those of an untrained recovery head whose shapes differ from the head the config builds (a base
    checkpoint starting the recovery stage of another head, `--policy.recovery_head`, which then starts from
    its own initialisation, as `refuse_unfit_weights` allows)."""
    wrong, other_head = [], []
    with safe_open(file, framework="pt") as saved:
        keys = set(saved.keys())
        untrained = RECOVERY_TRAINED in keys and not bool(saved.get_tensor(RECOVERY_TRAINED))
        for key in sorted(keys & set(state)):
            tensor = saved.get_slice(key)
            shape, dtype = tuple(tensor.get_shape()), tensor.get_dtype()
            # the outcome table's buffers are empty until loaded, then take the saved shapes
            if shape != tuple(state[key].shape) and state[key].numel():
                if untrained and key.startswith("model.recovery."):
                    other_head.append(key)
                else:
                    wrong.append(f"{key} has shape {shape}, the config makes {tuple(state[key].shape)}")
            elif state[key].is_floating_point() and not dtype.startswith(("F", "BF")):
                wrong.append(f"{key} holds {dtype}, not floats")
    if wrong:
        raise ValueError(
            f"The weights in {file} do not fit the ccdp policy its config describes: "
            f"{_listed(wrong, 'tensor(s)')}. If the checkpoint's config.json was edited (input_features, "
            "output_features, down_dims, kernel_size, ...), restore the values lerobot-train saved; "
            "otherwise the weights file was altered: train again, or copy or download the checkpoint again."
        )
    return other_head


def refuse_non_finite_weights(state: dict, path: str | Path) -> None:
    """Refuse loaded weights or buffers (the outcome table among them) holding NaN or inf, naming the
    tensors: they gave non-finite actions from the first `select_action`."""
    bad = [
        key for key, value in state.items() if value.is_floating_point() and not torch.isfinite(value).all()
    ]
    if bad:
        raise ValueError(
            f"The weights in {path} hold NaN or inf in {_listed(bad, 'tensor(s)')}: the training that saved "
            "them diverged or read non-finite data, or the file was altered. Use an earlier checkpoint "
            "(<output_dir>/checkpoints/<step>/pretrained_model) or train again."
        )


def _listed(keys: list[str], kind: str, shown: int = 3) -> str:
    more = ", ..." if len(keys) > shown else ""
    return f"{len(keys)} {kind} ({', '.join(keys[:shown])}{more})"


# The card's text, under lerobot_ccdp/templates/.
TEMPLATE = "ccdp_modelcard_template.md"


def make_model_card(
    config: CCDPConfig,
    dataset_repo_id: str,
    license: str | None,
    tags: list[str] | None,
    recovery_trained: bool,
) -> ModelCard:
    """The README of a pushed checkpoint: LeRobot's own template knows only its built-in policies ("Model type
    not recognized"), so ccdp's says which package provides the policy type and how the stages run. Same
    metadata as LeRobot's card, so the Hub lists it as a LeRobot robotics model."""
    card_data = ModelCardData(
        license=license or "apache-2.0",
        library_name="lerobot",
        pipeline_tag="robotics",
        tags=sorted(set(tags or []) | {"robotics", "lerobot", "ccdp", "failure-recovery"}),
        model_name="ccdp",
        datasets=dataset_repo_id,
    )
    template = files("lerobot_ccdp").joinpath("templates", TEMPLATE).read_text(encoding="utf-8")
    card = ModelCard.from_template(
        card_data,
        template_str=template,
        repo_id=config.repo_id or "<repo_id>",
        training_stage=config.training_stage,
        recovery_trained=recovery_trained,
        failure_feature=config.failure_feature,
    )
    card.validate()  # as LeRobot's card: the Hub refuses metadata it cannot parse
    return card


def checked_load(load: Callable[..., Any], path: str | Path, **kwargs) -> Any:
    """`CCDPPolicy.from_pretrained`: `load(config=..., **kwargs)` is LeRobot's own. A checkpoint carries its
    own outcome table. LeRobot's make_policy hands from_pretrained the dataset's metadata and stats too, and
    from_pretrained passes them on to __init__ (under lerobot-record: a new, empty recording dataset without
    the label column); they are dropped so that loading never reads a dataset. A local folder is checked
    first (`checkpoint_loading`): a wrong path or a damaged file is named with the fix; so is a checkpoint of
    another policy type or action size, or whose weights do not fit (`refuse_unfit_weights`). A
    `failure_signal_file` only the checkpoint names is dropped: a checkpoint never chooses a file to watch."""
    for key in ("dataset_meta", "dataset_stats"):
        kwargs.pop(key, None)
    with checkpoint_loading(path):
        hub = {key: kwargs[key] for key in HUB_DOWNLOAD_KEYS if key in kwargs}
        config = kwargs.pop("config", None) or PreTrainedConfig.from_pretrained(path, **hub)
        saved = saved_config(path, **hub)
        refuse_other_checkpoint(config, saved, path)
        ignore_saved_signal_file(config, saved)
        policy = load(config=config, **kwargs)
        refuse_unfit_weights(policy.state_dict(), bool(policy.model.recovery_trained), path, **hub)
        refuse_unfit_outcome_table(policy.state_dict(), policy.config, path)
        return policy
