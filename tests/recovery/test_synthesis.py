"""lerobot-ccdp-synthesize: recipe checks, z identical to the policy's, LeRobot loading and training,
atomicity."""

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
from lerobot.utils.constants import ACTION, OBS_STATE
from safetensors.torch import load_file
from torch import Tensor

from lerobot_ccdp.datasets.recipe_file import RecoveryRecipe
from lerobot_ccdp.envs import TASKS
from lerobot_ccdp.policy.configuration_ccdp import (
    FAILURE_FEATURE_KEY,
    SIBLING_COUNT_KEY,
    SIBLING_FEATURES_KEY,
    CCDPConfig,
)
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.policy.processor_ccdp import normalize_batch
from lerobot_ccdp.recovery import synthesize
from lerobot_ccdp.recovery.synthesize import (
    FAILURE_ACTION,
    PAIR_SOURCE,
    RECIPE_COPY,
    synthesize_recovery_dataset,
)

from fixtures.policy_factory import untrained_checkpoint
from fixtures.reaching import REACHING_REPO_ID, run_cli
from fixtures.recovery_rows import assert_rows_store_the_policys_z, normalized_rows

FEATURE_SETTINGS = {
    "primitive": {"failure_feature": "primitive", "num_primitives": 4},
    "final_state": {"failure_feature": "final_state", "failure_state_dims": [0, 1]},
    # A z of one dim is a column of shape (1,), which LeRobotDataset loads as a scalar per row.
    "final_state_1d": {"failure_feature": "final_state", "failure_state_dims": [1]},
    "action": {"failure_feature": "action"},
}
# Small and loose enough that an untrained base (near-random chunks) still yields pairs quickly.
SMALL = {
    "n_states": 16,
    "chunks_per_state": 6,
    "batch_states": 8,
    "pairs_per_failure": 2,
    "demo_frames": 200,
    "delta_x": 0.05,
}


@pytest.fixture(scope="module", params=list(FEATURE_SETTINGS))
def synthesised(request, reaching_root, tmp_path_factory) -> tuple[Path, Path, RecoveryRecipe]:
    settings = FEATURE_SETTINGS[request.param]
    tmp = tmp_path_factory.mktemp(f"synth_{request.param}")
    checkpoint = untrained_checkpoint(reaching_root, tmp / "base", **settings)
    recipe = RecoveryRecipe.from_dict({**SMALL})
    out = _synthesize_reaching(recipe, reaching_root, checkpoint, tmp / "recovery")
    return checkpoint, out, recipe


def test_recovery_dataset_loads_with_its_stats_and_recipe_record(synthesised, reaching_root):
    checkpoint, root, recipe = synthesised
    dataset = LeRobotDataset("local/recovery", root=root)
    item = dataset[0]
    assert item[ACTION].shape == (16, 2) and item[FAILURE_ACTION].shape == (16, 2)
    assert (
        item[FAILURE_FEATURE_KEY].numel() == CCDPPolicy.from_pretrained(checkpoint).config.failure_feature_dim
    )
    sources = torch.as_tensor(dataset.hf_dataset[PAIR_SOURCE]).flatten()
    assert (sources == 0).any() and (sources == 1).any(), (
        "recoveries both synthesised and drawn from the demos"
    )
    demo_stats = LeRobotDatasetMetadata(REACHING_REPO_ID, root=reaching_root).stats
    for key in (ACTION, OBS_STATE):  # lerobot-train normalises with these: they must be the base's
        torch.testing.assert_close(
            torch.as_tensor(dataset.meta.stats[key]["min"]), torch.as_tensor(demo_stats[key]["min"])
        )
        torch.testing.assert_close(
            torch.as_tensor(dataset.meta.stats[key]["max"]), torch.as_tensor(demo_stats[key]["max"])
        )
    record = yaml.safe_load((root / RECIPE_COPY).read_text())
    config = CCDPPolicy.from_pretrained(checkpoint).config
    # the recipe gives no delta_z: eq. (5) used the checkpoint's, the policy's distance for a repeat
    assert recipe.delta_z is None and record["recovery"]["delta_z"] == config.delta_z
    assert record["source"] == {
        "repo_id": REACHING_REPO_ID,
        "root": str(reaching_root),
        "policy_path": str(checkpoint),
    }
    result = record["result"]
    assert (
        result["rows"]
        == dataset.num_frames
        == result["recoveries_synthesised"] + result["recoveries_from_demos"]
    )
    assert result["pool_synthesised"] == 16 * 6 and result["pool_demo"] == 200
    assert dataset.num_frames <= 2 * (16 * 6 + 200), "at most pairs_per_failure recoveries per pool sample"


def test_stored_z_is_the_policys_z_of_the_failed_chunk(synthesised):
    assert_rows_store_the_policys_z(*synthesised[:2])


def test_every_row_satisfies_eq5(synthesised):
    """The recovery chunk's z differs from the failure's by more than delta_z (the state condition is checked
    between perturbed windows inside the recipe; here the stored z and chunks are re-read from disk)."""
    policy, normalized = normalized_rows(*synthesised[:2], chunk_column=ACTION)
    z_recovery = policy.model.feature.from_chunk(normalized[ACTION], policy.model.outcomes)
    distance = ((z_recovery - normalized[FAILURE_FEATURE_KEY]) ** 2).sum(dim=-1)
    assert (distance > policy.config.delta_z - 1e-4).all()


# Real lerobot-train runs for a z of several dims and for one of one dim (a scalar column in LeRobot's
# batches).
def _synthesize_reaching(recipe: RecoveryRecipe, reaching_root: Path, checkpoint: Path, out: Path) -> Path:
    """The recovery dataset of `recipe` from the 2-D demos and `checkpoint`, as `local/recovery` at `out`."""
    return synthesize_recovery_dataset(
        recipe, REACHING_REPO_ID, reaching_root, checkpoint, "local/recovery", out, progress=False
    )


def _train_recovery_stage(checkpoint: Path, root: Path, out: Path, steps: int, *overrides: str) -> None:
    """lerobot-train's recovery stage from `checkpoint` on the rows at `root`, as a user runs it."""
    run_cli(
        "lerobot-train",
        *overrides,
        f"--policy.path={checkpoint}",
        "--policy.training_stage=recovery",
        "--dataset.repo_id=local/recovery",
        f"--dataset.root={root}",
        f"--output_dir={out}",
        f"--steps={steps}",
        "--batch_size=16",
        f"--save_freq={steps}",
        "--policy.push_to_hub=false",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--log_freq={steps // 2}",
    )


# Both slow (about 35 s each on the slower machine): the recovery stage trains through lerobot-train in the
# pipeline test (`primitive`) and in the set denoiser's test below; the scalar-column z of `final_state_1d`
# loads through LeRobotDataset in the fixture's tests, and through lerobot-train only here.
@pytest.mark.slow
@pytest.mark.parametrize("synthesised", ["primitive", "final_state_1d"], indirect=True)
def test_lerobot_train_recovery_stage_on_the_synthesised_dataset(synthesised, tmp_path):
    checkpoint, root, _ = synthesised
    out = tmp_path / "recovery_run"
    _train_recovery_stage(checkpoint, root, out, steps=20)
    trained = out / "checkpoints" / "last" / "pretrained_model"
    before, after = load_file(checkpoint / "model.safetensors"), load_file(trained / "model.safetensors")
    assert bool(after["model.recovery_trained"]) and not bool(before["model.recovery_trained"])
    for key, value in before.items():
        if key.startswith("model.base."):
            torch.testing.assert_close(after[key], value, msg=f"{key} changed: the base must stay frozen")
        if key.startswith("model.outcomes."):
            torch.testing.assert_close(after[key], value, msg=f"{key}: the outcome table must travel along")
    assert any(not torch.equal(after[k], before[k]) for k in before if k.startswith("model.recovery."))
    policy = CCDPPolicy.from_pretrained(trained)
    assert (
        policy.config.training_stage == "recovery"
        and policy.config.input_features == CCDPPolicy.from_pretrained(checkpoint).config.input_features
    )


def test_interrupted_synthesis_leaves_nothing(reaching_root, tmp_path, monkeypatch):
    checkpoint = untrained_checkpoint(reaching_root, tmp_path / "base", **FEATURE_SETTINGS["primitive"])
    recipe = RecoveryRecipe.from_dict({**SMALL})
    original = synthesize.LeRobotDataset.add_frame
    calls = {"n": 0}

    def interrupt_midway(self, frame):
        calls["n"] += 1
        if calls["n"] == 50:
            raise KeyboardInterrupt
        return original(self, frame)

    monkeypatch.setattr(synthesize.LeRobotDataset, "add_frame", interrupt_midway)
    with pytest.raises(KeyboardInterrupt):
        _synthesize_reaching(recipe, reaching_root, checkpoint, tmp_path / "recovery")
    assert calls["n"] == 50
    assert sorted(p.name for p in tmp_path.iterdir()) == ["base"], "no dataset and no staging folder left"


def test_outcome_radius_keeps_only_sampled_chunks_near_a_demonstration(reaching_root, tmp_path):
    """Sampled chunks borrow the outcome of their nearest demonstrated chunk; with outcome_radius those
    farther than the radius from every demonstrated chunk leave the pool, while demonstrated chunks all
    stay."""
    settings = FEATURE_SETTINGS["primitive"]
    checkpoint = untrained_checkpoint(reaching_root, tmp_path / "base", **settings)
    policy = CCDPPolicy.from_pretrained(checkpoint)

    def synthesised_gaps(radius: float, name: str) -> tuple[Tensor, dict]:
        recipe = RecoveryRecipe.from_dict({**SMALL, "outcome_radius": radius})
        root = synthesize_recovery_dataset(
            recipe, REACHING_REPO_ID, reaching_root, checkpoint, "local/r", tmp_path / name, progress=False
        )
        rows = LeRobotDataset("local/r", root=root).hf_dataset.with_format("torch")[:]
        chunks = normalize_batch(
            policy.config, LeRobotDatasetMetadata("local/r", root=root).stats, {ACTION: rows[ACTION]}
        )[ACTION][rows[PAIR_SOURCE].flatten() == 0]
        result = yaml.safe_load((root / RECIPE_COPY).read_text())["result"]
        return policy.model.outcomes.rms_distance(chunks), result

    gaps, unfiltered = synthesised_gaps(0.0, "all")
    radius = float(gaps.median())
    kept, filtered = synthesised_gaps(radius, "near")
    assert unfiltered["pool_synthesised"] == unfiltered["sampled"] and (gaps > radius + 1e-4).any()
    assert 0 < filtered["pool_synthesised"] < filtered["sampled"]
    assert len(kept) and (kept <= radius + 1e-4).all()
    assert filtered["pool_demo"] == unfiltered["pool_demo"]


def test_refuses_an_outcome_radius_that_drops_every_sampled_chunk(reaching_root, tmp_path):
    checkpoint = untrained_checkpoint(reaching_root, tmp_path / "base", **FEATURE_SETTINGS["primitive"])
    recipe = RecoveryRecipe.from_dict({**SMALL, "outcome_radius": 1e-6})
    with pytest.raises(ValueError, match="Raise outcome_radius"):
        synthesize_recovery_dataset(
            recipe, REACHING_REPO_ID, reaching_root, checkpoint, "local/r", tmp_path / "r", progress=False
        )
    assert not (tmp_path / "r").exists()


def test_refuses_a_recipe_that_defines_z_differently(reaching_root, tmp_path):
    checkpoint = untrained_checkpoint(reaching_root, tmp_path / "base", **FEATURE_SETTINGS["primitive"])
    recipe = RecoveryRecipe.from_dict({**FEATURE_SETTINGS["final_state"], **SMALL})
    with pytest.raises(ValueError, match="--policy.failure_feature=final_state"):
        synthesize_recovery_dataset(
            recipe, REACHING_REPO_ID, reaching_root, checkpoint, "local/r", tmp_path / "r", progress=False
        )
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("settings", ["final_state_1d", "primitive"])
def test_without_a_recipe_z_is_the_checkpoints(reaching_root, tmp_path, settings):
    """README's `lerobot-ccdp-synthesize --policy.path --dataset.* --output.root`: no recipe file and no z
    flag; every z setting is read from the base checkpoint, and the rows are dataset local/<output folder>."""
    checkpoint = untrained_checkpoint(reaching_root, tmp_path / "base", **FEATURE_SETTINGS[settings])
    out = tmp_path / "my_rows"
    small = [f"--recovery.{k}={v}" for k, v in SMALL.items()]
    demos = [f"--dataset.repo_id={REACHING_REPO_ID}", f"--dataset.root={reaching_root}"]
    synthesize.main([f"--policy.path={checkpoint}", *demos, f"--output.root={out}", *small])

    config = CCDPPolicy.from_pretrained(checkpoint).config
    record = yaml.safe_load((out / RECIPE_COPY).read_text())["recovery"]
    z_fields = (
        "failure_feature",
        "failure_state_dims",
        "primitive_key",
        "num_primitives",
    )
    assert {k: record[k] for k in z_fields} == {k: getattr(config, k) for k in z_fields}
    assert record["delta_z"] == config.delta_z  # eq. (5)'s threshold: the policy's distance for a repeat
    assert LeRobotDataset("local/my_rows", root=out).num_frames > 0
    assert_rows_store_the_policys_z(checkpoint, out)


def test_a_recipe_naming_some_z_settings_takes_the_others_from_the_checkpoint():
    config = CCDPConfig(failure_feature="final_state", failure_state_dims=[0, 2])
    recipe = RecoveryRecipe.from_dict({"failure_state_dims": [0, 2], "sigma": 0.05})
    resolved = recipe.for_checkpoint(config, "recipe.yaml")
    assert resolved.failure_feature == "final_state" and resolved.failure_state_dims == [0, 2]
    assert resolved.num_primitives == 0 and resolved.sigma == 0.05
    with pytest.raises(ValueError, match=r"failure_state_dims: recipe \[1\] vs checkpoint \[0, 2\]"):
        RecoveryRecipe(failure_state_dims=[1]).for_checkpoint(config, "recipe.yaml")


def test_refuses_a_demo_dataset_without_the_named_feature(reaching_root, tmp_path):
    settings = {"failure_feature": "primitive", "num_primitives": 4, "primitive_key": "option"}
    checkpoint = untrained_checkpoint(
        reaching_root, tmp_path / "base", **{**settings, "primitive_key": "primitive"}
    )
    policy = CCDPPolicy.from_pretrained(checkpoint)
    policy.config.primitive_key = "option"  # a checkpoint whose recipe names a column the demos lack
    policy.save_pretrained(checkpoint)
    recipe = RecoveryRecipe.from_dict({**SMALL})
    with pytest.raises(ValueError, match=r"lacks column\(s\) \['option'\]"):
        synthesize_recovery_dataset(
            recipe, REACHING_REPO_ID, reaching_root, checkpoint, "local/r", tmp_path / "r", progress=False
        )
    assert not (tmp_path / "r").exists()


def test_refuses_demo_siblings_for_a_head_without_siblings(reaching_root, tmp_path):
    """Only the set denoiser's rows carry siblings: the flag would otherwise change nothing, silently."""
    checkpoint = untrained_checkpoint(reaching_root, tmp_path / "base", **FEATURE_SETTINGS["primitive"])
    recipe = RecoveryRecipe.from_dict({**SMALL, "demo_siblings": True})
    with pytest.raises(ValueError, match="recovery.demo_siblings .* recovery_head='unet'"):
        synthesize_recovery_dataset(
            recipe, REACHING_REPO_ID, reaching_root, checkpoint, "local/r", tmp_path / "r", progress=False
        )
    assert not (tmp_path / "r").exists()


def test_a_set_denoiser_base_writes_the_eps_z_heads_pairs_when_asked(reaching_root, tmp_path):
    """`--policy.recovery_head=unet` on a base whose own head is the set denoiser writes the pairs of eq. (5)
    that eq. (4)'s eps_z heads train on (the benchmark's `ccdp_eps_z` column, beside the task's own head),
    not the set denoiser's one-chunk rows, and records the head it wrote for; the recipe's set-denoiser
    option `demo_siblings` is refused for them with the flag that turns it off."""
    settings = {**FEATURE_SETTINGS["primitive"], "recovery_head": "set_denoiser", "history_length": 0}
    checkpoint = untrained_checkpoint(reaching_root, tmp_path / "base", **settings)
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(yaml.safe_dump({"recovery": {**SMALL, "demo_siblings": True}}))
    command = [
        f"--config_path={recipe}",
        f"--dataset.repo_id={REACHING_REPO_ID}",
        f"--dataset.root={reaching_root}",
        f"--policy.path={checkpoint}",
        "--policy.recovery_head=unet",
        f"--output.root={tmp_path / 'pairs'}",
    ]
    with pytest.raises(ValueError, match=r"recovery_head='unet': pass --recovery.demo_siblings=false"):
        synthesize.main(command)
    synthesize.main([*command, "--recovery.demo_siblings=false"])
    rows = LeRobotDataset("local/pairs", root=tmp_path / "pairs")
    assert FAILURE_ACTION in rows.features and SIBLING_FEATURES_KEY not in rows.features
    assert yaml.safe_load((tmp_path / "pairs" / RECIPE_COPY).read_text())["recovery_head"] == "unet"
    # every row a pair of eq. (5): the recovery's z away from the failure's
    policy, normalized = normalized_rows(checkpoint, tmp_path / "pairs", chunk_column=ACTION)
    z_recovery = policy.model.feature.from_chunk(normalized[ACTION], policy.model.outcomes)
    distance = ((z_recovery - normalized[FAILURE_FEATURE_KEY]) ** 2).sum(dim=-1)
    assert len(distance) and (distance > policy.config.delta_z - 1e-4).all()
    with pytest.raises(ValueError, match=r"recovery_head='unett' names no head"):
        synthesize.main([*command[:-2], "--policy.recovery_head=unett", f"--output.root={tmp_path / 'x'}"])
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"w_s": 1.5}, r"w_s must be in \(0, 1\]"),
        ({"failure_feature": "colour"}, "failure_feature must be one of"),
        ({"n_states": 0, "demo_frames": 0}, "the pool is empty"),
        ({"pairs_per_failure": 0}, "pairs_per_failure"),
        ({"delta_x": -1.0}, "delta_x"),
        ({"outcome_radius": -0.1}, "outcome_radius"),
        ({"sigmaa": 0.1}, "unknown field"),
        ({"sigma": "0.02"}, r"recovery.sigma must be float, got '0.02'"),
        ({"chunks_per_state": 2.5}, "recovery.chunks_per_state must be int, got 2.5"),
    ],
)
def test_recipe_validation(change, message):
    with pytest.raises(ValueError, match=message):
        RecoveryRecipe.from_dict(change)


def test_paths_are_checked_before_loading_anything(reaching_root, tmp_path):
    """A wrong --output.root or --dataset.root is named at once, not after minutes of loading and sampling."""
    recipe = RecoveryRecipe.from_dict({**SMALL})
    missing_checkpoint = tmp_path / "no_such_checkpoint"
    (tmp_path / "out").mkdir()  # an empty folder receives the dataset; one holding a user's file does not
    (tmp_path / "out" / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="out.*already exists"):
        synthesize_recovery_dataset(
            recipe,
            REACHING_REPO_ID,
            reaching_root,
            missing_checkpoint,
            "local/r",
            tmp_path / "out",
            progress=False,
        )
    with pytest.raises(ValueError, match="only replaces a dataset that lerobot_ccdp wrote"):
        synthesize_recovery_dataset(
            recipe,
            REACHING_REPO_ID,
            reaching_root,
            missing_checkpoint,
            "local/r",
            tmp_path / "out",
            overwrite=True,
            progress=False,
        )
    with pytest.raises(FileNotFoundError, match=f"No LeRobot dataset at --dataset.root={tmp_path / 'demos'}"):
        synthesize_recovery_dataset(
            recipe,
            REACHING_REPO_ID,
            tmp_path / "demos",
            missing_checkpoint,
            "local/r",
            tmp_path / "new",
            progress=False,
        )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_every_task_recipe_has_a_valid_recovery_section():
    recipes = sorted(Path(__file__).parents[2].joinpath("datasets_recipes").glob("*.yaml"))
    # every task, four also with cameras, five without labels, the 2-D task
    assert len(recipes) == len(TASKS) + 10
    for path in recipes:
        RecoveryRecipe.load(path)


def test_set_denoiser_rows_are_chunks_sampled_at_demonstrated_states_and_train_through_lerobot_train(
    reaching_root, tmp_path
):
    """With `recovery_head=set_denoiser` every row is one chunk of its own, sampled (or demonstrated) at a
    demonstrated state, half of them where an option starts (here one per episode: its first state),
    perturbed by eq. 6, with its own z; lerobot-train's recovery stage then trains eps_{s,F} from the copied
    base while the base stays frozen."""
    settings = {**FEATURE_SETTINGS["primitive"], "recovery_head": "set_denoiser", "history_length": 0}
    checkpoint = untrained_checkpoint(reaching_root, tmp_path / "base", **settings)
    recipe = RecoveryRecipe.from_dict({**SMALL, "sigma": 0.0})
    root = _synthesize_reaching(recipe, reaching_root, checkpoint, tmp_path / "recovery")
    demos = LeRobotDataset(REACHING_REPO_ID, root=reaching_root).hf_dataset.with_format("torch")[:]
    starts = demos[OBS_STATE][demos["frame_index"].flatten() == 0]
    rows = LeRobotDataset("local/recovery", root=root)
    assert rows.num_frames == 16 * 6 + SMALL["demo_frames"]  # every sampled chunk, and the demonstrated ones
    states = rows.hf_dataset.with_format("torch")[:][OBS_STATE]
    # sigma 0: demonstrated states (up to the normalisation's round trip), a share of them the first states
    assert torch.cdist(states, demos[OBS_STATE]).min(dim=1).values.max() < 1e-3
    at_start = torch.cdist(states, starts).min(dim=1).values < 1e-3
    assert 0.25 < at_start.float().mean() < 0.75, at_start.float().mean()
    policy, normalized = normalized_rows(checkpoint, root, chunk_column=ACTION)
    torch.testing.assert_close(
        normalized[FAILURE_FEATURE_KEY],
        policy.model.feature.from_chunk(normalized[ACTION], policy.model.outcomes),
    )
    # Beside each sampled row, the z of the 6 chunks sampled at its state, its own among them; none beside a
    # demonstrated chunk.
    columns = rows.hf_dataset.with_format("torch")[:]
    siblings, count = columns[SIBLING_FEATURES_KEY], columns[SIBLING_COUNT_KEY].reshape(-1)
    sampled = 16 * 6
    assert count[:sampled].eq(6).all() and count[sampled:].eq(0).all() and siblings[sampled:].eq(0).all()
    per_state = normalized[FAILURE_FEATURE_KEY][:sampled].reshape(16, 1, 6, 4).expand(16, 6, 6, 4)
    torch.testing.assert_close(siblings[:sampled], per_state.reshape(sampled, 6, 4), atol=1e-4, rtol=1e-4)
    out = tmp_path / "set_run"
    _train_recovery_stage(checkpoint, root, out, 10, "--policy.stratum_weights=true")
    before = load_file(checkpoint / "model.safetensors")
    after = load_file(out / "checkpoints" / "last" / "pretrained_model" / "model.safetensors")
    assert bool(after["model.recovery_trained"])
    assert all(torch.equal(after[k], v) for k, v in before.items() if k.startswith("model.base."))
    # the head started as a copy of the base ...
    unet = "model.recovery.unet.mid_modules.0.conv1.block.0.weight"
    # ... and trained away from it
    assert not torch.equal(after[unet], after[unet.replace("model.recovery.", "model.base.")])


def test_set_denoiser_rows_start_at_every_demonstrated_option_not_only_at_episode_starts():
    """Packing and the Bartender decide twice per episode: after a failed second decision the env restores the
    robot where that option began, so the set denoiser's rows are drawn there too. Options end where
    `failure_segments` says (labels here, gripper drops without labels)."""
    episodes = np.array([0, 0, 0, 0, 0, 1, 1, 1])
    labels = np.array([3, 3, 1, 1, 1, 2, 2, 2])
    labelled = CCDPConfig(failure_feature="primitive", num_primitives=4)
    assert synthesize.option_starts(labelled, episodes, np.zeros((8, 2)), labels).tolist() == [0, 2, 5]
    assert synthesize.option_starts(labelled, episodes, np.zeros((8, 2)), None).tolist() == [0, 5]
    # Episode 0 closes the gripper, opens it at frame 3 (the drop's option ends there, with its opening
    # command) and starts a second option at frame 4; episode 1 drops its object at its last frame.
    gripper = np.array([-1, 1, 1, -1, 1, -1, 1, -1.0])
    actions = np.stack([np.arange(8.0), gripper], axis=1)  # the arm never holds still
    dropped = CCDPConfig(failure_feature="final_state", failure_segments="drops")
    assert synthesize.option_starts(dropped, episodes, actions, None).tolist() == [0, 4, 5]


def test_set_denoiser_states_are_drawn_half_at_option_starts_and_half_along_the_demonstrations():
    """An attempt spans several plans, each composed with the failure set, so the set denoiser's states cover
    the demonstrations as well as the option starts where F decides."""
    demos = synthesize.Demos(
        windows=torch.zeros(10, 1, 2), chunks=torch.zeros(10, 4, 2), starts=torch.tensor([0, 5])
    )
    frames = synthesize.set_denoiser_frames(demos)
    assert torch.bincount(frames, minlength=10).tolist() == [6, 1, 1, 1, 1, 6, 1, 1, 1, 1]


def sibling_pool() -> synthesize.Samples:
    """Eight pool samples, z = 0..7: states 0, 1 and 2 kept 3, 1 and 2 of their 4 chunks (outcome_radius),
    drawn at demo frames 7, 2 and 7; two demonstrated chunks (state -1) of frames 7 and 4."""
    state_id = torch.tensor([0, 0, 0, 1, 2, 2, -1, -1])
    frame = torch.tensor([7, 7, 7, 2, 7, 7, 7, 4])
    z = torch.arange(8.0)[:, None]
    return synthesize.Samples(
        torch.zeros(8, 1, 2), torch.zeros(8, 4, 2), z, (state_id < 0).long(), state_id, frame
    )


def test_siblings_are_the_outcomes_sampled_at_the_same_state_however_many_outcome_radius_kept():
    """State 0 kept 3 of its 4 chunks, state 1 one, state 2 two; demonstrated chunks (state -1) have none."""
    siblings, count = synthesize.sibling_outcomes(sibling_pool(), chunks_per_state=4)
    assert count.tolist() == [3, 3, 3, 1, 2, 2, 0, 0]
    assert siblings[1, :, 0].tolist() == [0, 1, 2, 0] and siblings[3, :, 0].tolist() == [3, 0, 0, 0]
    assert siblings[5, :, 0].tolist() == [4, 5, 0, 0] and siblings[6:].eq(0).all()


def test_demo_siblings_are_those_of_the_first_state_drawn_at_the_demonstrated_frame():
    """States 0 and 2 were drawn at frame 7, state 1 at frame 2: the demonstrated chunk of frame 7 takes state
    0's outcomes, that of frame 4, where no state was drawn, keeps none."""
    siblings, count = synthesize.sibling_outcomes(sibling_pool(), chunks_per_state=4, demo_siblings=True)
    assert count.tolist() == [3, 3, 3, 1, 2, 2, 3, 0]
    assert siblings[6, :, 0].tolist() == [0, 1, 2, 0] and siblings[7].eq(0).all()
