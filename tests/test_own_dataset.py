"""README "Train on a local dataset" on a dataset this project did not record: one made with LeRobot's own
`LeRobotDataset.create` / `add_frame` / `save_episode`, with a camera and no option labels, taken through
the section's three commands as written (in-process, through the console scripts' entry points, with only
the step counts and sizes made small) to a checkpoint that recovers: its recovery head is trained and a
reported failure changes the next plan."""

from pathlib import Path

import numpy as np
import torch
import yaml
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_ccdp.datasets.camera_windows import video_backend
from lerobot_ccdp.datasets.configs import SynthesizeConfig, parse_cli
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy
from lerobot_ccdp.recovery.synthesize import RECIPE_COPY

from fixtures.doc_commands import commands, run_command, sized

REPO = Path(__file__).resolve().parent.parent
CAMERA, SIZE, FPS = "observation.images.front", 64, 10
SECTION = (REPO / "README.md").read_text().split("## Train on a local dataset\n", 1)[1].split("\n#", 1)[0]


def record_with_lerobot(root: Path, repo_id: str) -> None:
    """Six reaches to one of two goals (left, right) from one start, with a camera that sees the hand, as a
    LeRobot user records them: LeRobot's dataset API, video storage, no option label column."""
    features = {
        OBS_STATE: {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
        CAMERA: {"dtype": "video", "shape": (SIZE, SIZE, 3), "names": ["height", "width", "channels"]},
        ACTION: {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
    }
    dataset = LeRobotDataset.create(repo_id, fps=FPS, features=features, root=root, use_videos=True)
    for episode in range(6):
        goal = np.array([1.0 if episode % 2 else -1.0, 0.5], dtype=np.float32)
        positions = [goal * min(t / 12, 1.0) for t in range(25)]
        for t, position in enumerate(positions):
            image = np.zeros((SIZE, SIZE, 3), dtype=np.uint8)
            column = int((position[0] + 1) / 2 * (SIZE - 8))
            image[24:40, column : column + 8] = 255  # the hand, where it is
            action = positions[min(t + 1, len(positions) - 1)]
            dataset.add_frame({OBS_STATE: position, CAMERA: image, ACTION: action, "task": "reach a goal"})
        dataset.save_episode()
    dataset.finalize()


def first_plan(policy: CCDPPolicy, pre, observation: dict, failed: bool) -> torch.Tensor:
    """The first action of the plan drawn at `observation` (after one failed attempt if `failed`), from the
    same noise either way (torch's global generator: each rollout's own stream would differ)."""
    policy.config.row_noise_streams = False
    policy.reset()
    with torch.inference_mode():
        torch.manual_seed(0)
        policy.select_action(pre(observation))
        if failed:
            policy.report_failure()
        torch.manual_seed(1)
        return policy.predict_action_chunk(pre(observation))[0, 0]


def test_the_readme_path_turns_a_lerobot_dataset_into_a_recovering_policy(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the README's relative paths, as typed from a clone's root
    _, *typed = commands(SECTION)  # the README's dataset command: a dataset recorded with LeRobot instead
    train_base, synthesise, train_recovery = (
        [arg.replace("reaching2d", "my_robot") for arg in argv] for argv in typed
    )
    demos = Path(next(a for a in train_base if a.startswith("--dataset.root=")).split("=", 1)[1])
    record_with_lerobot(demos, "local/my_robot")
    assert "primitive" not in (demos / "meta" / "info.json").read_text()  # no option label column

    # where torchcodec cannot load, the fix docs/troubleshooting.md gives
    train_base.append(f"--dataset.video_backend={video_backend()}")
    for argv in (train_base, synthesise, train_recovery):
        run_command(sized(argv), monkeypatch)

    base_path = Path("outputs/my_robot/base/checkpoints/last/pretrained_model")
    ccdp_path = Path("outputs/my_robot/ccdp/checkpoints/last/pretrained_model")
    base, ccdp = CCDPPolicy.from_pretrained(base_path), CCDPPolicy.from_pretrained(ccdp_path)
    # The recovery rows: z from the base (final_state, no labels), under the repo id the README names.
    rows = yaml.safe_load((Path("data/my_robot_recovery") / RECIPE_COPY).read_text())
    assert rows["recovery"]["failure_feature"] == base.config.failure_feature == "final_state"
    assert (
        LeRobotDataset("local/my_robot_recovery", root="data/my_robot_recovery").num_frames
        == rows["result"]["rows"]
    )

    # The third command trained the recovery head over the first's frozen base.
    assert not bool(base.model.recovery_trained) and bool(ccdp.model.recovery_trained)
    assert (
        ccdp.config.training_stage == "recovery" and ccdp.config.image_features == base.config.image_features
    )
    trained, frozen = ccdp.model.state_dict(), base.model.state_dict()
    for name, value in frozen.items():
        if name.startswith(("base.", "images.")):
            torch.testing.assert_close(trained[name], value, msg=f"{name} moved in the recovery stage")
    assert any(not torch.equal(trained[n], v) for n, v in frozen.items() if n.startswith("recovery."))
    assert len(ccdp.model.outcomes) == len(base.model.outcomes) > 0

    # On a robot (README "Use it on a robot"): a reported failure changes the next plan of the recovering
    # checkpoint; the base-only checkpoint plans the same either way (DP).
    observation = {OBS_STATE: torch.zeros(1, 2), CAMERA: torch.rand(1, 3, SIZE, SIZE)}
    for policy, path, changes in ((ccdp, ccdp_path, True), (base, base_path, False)):
        pre, _ = make_pre_post_processors(policy.config, str(path))
        after_failure = first_plan(policy, pre, observation, failed=True)
        without = first_plan(policy, pre, observation, failed=False)
        assert (not torch.allclose(after_failure, without)) is changes, path


def test_synthesis_needs_no_recipe_file():
    """The README's second command parses as written: every recovery setting has a default, z comes from the
    checkpoint (see test_synthesis's recipe-free run), and the rows' repo id is local/<output folder>."""
    (synthesise,) = [argv for argv in commands(SECTION) if argv[0] == "lerobot-ccdp-synthesize"]
    cfg = parse_cli(SynthesizeConfig, synthesise[1:])
    assert cfg.recovery.failure_feature is None and cfg.recovery.failure_settings() == {}
    assert cfg.output.repo_id == "local/reaching2d_recovery"
    (recovery,) = [argv for argv in commands(SECTION) if "--policy.training_stage=recovery" in argv]
    assert (
        f"--dataset.repo_id={cfg.output.repo_id}" in recovery
        and f"--dataset.root={cfg.output.root}" in recovery
    )
