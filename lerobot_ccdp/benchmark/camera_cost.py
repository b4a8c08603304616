"""CCDP versus LeRobot's stock DiffusionPolicy with a camera: planning latency and training step,
side by side.

    HF_HUB_OFFLINE=1 MUJOCO_GL=egl python -m lerobot_ccdp.benchmark.camera_cost [--size 64] [--repeats 30]
        [--train-steps 20] [--cli-steps 40 | --no-cli] [--threads 2]
        [--out outputs/camera_cost.json]

Both policies see one camera of --size x --size pixels and the ccdp tasks' 4-D robot state, encoded by
LeRobot's RGB encoder with the same settings (ResNet-18 with all 4 stages, 32 spatial-softmax keypoints, group
norm, no crop), with policy_cost's UNet and sampling settings (SHARED).

(a) Planning latency: `predict_action_chunk` at batch 1 (the camera encoded once per plan), median over
    --repeats interleaved calls; CCDP at N = 0 and 4 failures (eps_z marked trained so the failure terms run).
(b) Training step (forward, backward, Adam), batch --batch-size, interleaved medians: CCDP with
    history_length 0 and 2 (its default: the camera of every history frame is encoded too) against diffusion.
(c) Render size: per --sizes, milliseconds to step DoorOpening-lite-v0 with its front camera rendered, and the
    training step of CCDP with the pixel task configs' encoder (3 ResNet stages) at that size.
(b') Real lerobot-train runs on --cli-episodes recorded pixel demos of DoorOpening-lite-v0 (video, decoded
    with pyav): steps/s from lerobot-train's own timers for diffusion, CCDP at history_length 0 and 2 (same
    encoder), and CCDP with the pixel task configs' encoder (`--policy.vision_backbone_stages=3`).
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
from lerobot.utils.utils import init_logging

from lerobot_ccdp.benchmark.policy_cost import (
    SHARED,
    interleaved_medians,
    lerobot_train_speed,
    recorded_once,
    write_results,
)
from lerobot_ccdp.benchmark.results import command_line
from lerobot_ccdp.benchmark.work_folder import add_work_arguments, claim_work
from lerobot_ccdp.policy.configuration_ccdp import CCDPConfig
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy

logger = logging.getLogger(__name__)
CREATED_BY = "lerobot_ccdp.benchmark.camera_cost"
STATE, CAMERA, ACTION = "observation.state", "observation.images.front", "action"
TASK, REPO_ID = "DoorOpening-lite-v0", "local/door_pixels_bench"
LATENCY_TARGET, TRAIN_TARGET = 1.5, 1.1


def features(size: int) -> tuple[dict, dict]:
    inputs = {
        STATE: PolicyFeature(FeatureType.STATE, (4,)),
        CAMERA: PolicyFeature(FeatureType.VISUAL, (3, size, size)),
    }
    return inputs, {ACTION: PolicyFeature(FeatureType.ACTION, (4,))}


def make_ccdp(size: int, **overrides) -> CCDPPolicy:
    inputs, outputs = features(size)
    return CCDPPolicy(
        CCDPConfig(
            input_features=inputs,
            output_features=outputs,
            device="cpu",
            failure_feature="action",
            **SHARED,
            **overrides,
        )
    )


def make_diffusion(size: int) -> DiffusionPolicy:
    inputs, outputs = features(size)
    return DiffusionPolicy(
        DiffusionConfig(input_features=inputs, output_features=outputs, device="cpu", **SHARED)
    )


def planning_latency(size: int, repeats: int, warmup: int) -> dict:
    torch.manual_seed(0)
    obs = {STATE: torch.randn(1, 4), CAMERA: torch.rand(1, 3, size, size)}
    diffusion = make_diffusion(size).eval()
    diffusion.reset()
    diffusion.select_action(dict(obs))
    # Stock diffusion plans from its queues, keyed by the stacked cameras select_action adds as
    # observation.images.
    stacked = {**obs, "observation.images": obs[CAMERA].unsqueeze(-4)}
    calls = {"diffusion": lambda: diffusion.predict_action_chunk(dict(stacked))}
    for n in (0, 4):
        policy = make_ccdp(size).eval()
        policy.model.recovery_trained.fill_(True)
        policy.select_action(dict(obs))
        for _ in range(n):
            policy.report_failure(rows=[0], z=torch.randn(1, policy.config.failure_feature_dim))
        calls[f"ccdp N={n}"] = lambda p=policy: p.predict_action_chunk(dict(obs))
    with torch.no_grad():
        medians = interleaved_medians(calls, repeats, warmup)
    return {"median_ms": medians, "ratio": {k: v / medians["diffusion"] for k, v in medians.items()}}


def training_step_time(size: int, batch_size: int, steps: int, warmup: int) -> dict:
    torch.manual_seed(0)
    setups = {"diffusion": make_diffusion(size)} | {
        f"ccdp H={h}": make_ccdp(size, history_length=h) for h in (0, 2)
    }

    def batch_for(policy) -> dict:
        cfg = policy.config
        history = getattr(cfg, "history_length", 0)
        frames, steps_ = history + cfg.n_obs_steps, history + cfg.horizon
        return {
            STATE: torch.rand(batch_size, frames, 4) * 2 - 1,
            CAMERA: torch.rand(batch_size, frames, 3, size, size),
            ACTION: torch.rand(batch_size, steps_, 4) * 2 - 1,
            "action_is_pad": torch.zeros(batch_size, steps_, dtype=torch.bool),
        }

    def step_fn(policy, batch):
        params = list(policy.get_optim_params())
        optimizer = torch.optim.Adam(params, lr=1e-4)

        def step():
            optimizer.zero_grad(set_to_none=True)
            policy.forward(batch)[0].backward()
            optimizer.step()

        return step

    calls = {name: step_fn(policy.train(), batch_for(policy)) for name, policy in setups.items()}
    medians = interleaved_medians(calls, steps, warmup)
    return {"median_ms": medians, "ratio": {k: v / medians["diffusion"] for k, v in medians.items()}}


def render_sizes(sizes: list[int], batch_size: int, steps: int, warmup: int) -> dict:
    """Why the tasks render 64 x 64: what each size costs per env step and per training step."""
    import gymnasium as gym
    import numpy as np

    from lerobot_ccdp.envs import gym_id

    results = {}
    for size in sizes:
        env = gym.make(
            gym_id(TASK), obs_type="pixels_agent_pos", observation_width=size, observation_height=size
        )
        env.reset(seed=0)
        action = np.zeros(env.action_space.shape, dtype=np.float32)
        step_ms = interleaved_medians({"env": lambda e=env, a=action: e.step(a)}, 50, 5)["env"]
        env.close()
        torch.manual_seed(0)
        policy = make_ccdp(size, history_length=0, vision_backbone_stages=3).train()
        batch = {
            STATE: torch.rand(batch_size, 1, 4),
            CAMERA: torch.rand(batch_size, 1, 3, size, size),
            ACTION: torch.rand(batch_size, policy.config.horizon, 4),
            "action_is_pad": torch.zeros(batch_size, policy.config.horizon, dtype=torch.bool),
        }
        optimizer = torch.optim.Adam(list(policy.get_optim_params()), lr=1e-4)

        def train_step(p=policy, b=batch, o=optimizer):
            o.zero_grad(set_to_none=True)
            p.forward(b)[0].backward()
            o.step()

        results[size] = {
            "env_step_ms": step_ms,
            "train_step_ms": interleaved_medians({"train": train_step}, steps, warmup)["train"],
        }
    return results


def lerobot_train_runs(root: Path, work: Path, steps: int, batch_size: int) -> dict:
    common = [
        f"--dataset.repo_id={REPO_ID}",
        f"--dataset.root={root}",
        "--dataset.video_backend=pyav",
        f"--steps={steps}",
        f"--batch_size={batch_size}",
        "--policy.push_to_hub=false",
        "--num_workers=0",
        "--wandb.enable=false",
        f"--log_freq={max(steps // 4, 1)}",
        "--save_checkpoint=false",
        "--seed=0",
        "--policy.device=cpu",
        "--policy.n_obs_steps=1",
        "--policy.horizon=16",
        "--policy.n_action_steps=8",
        "--policy.down_dims=[32,64,128]",
        "--policy.diffusion_step_embed_dim=32",
        "--policy.noise_scheduler_type=DDIM",
        "--policy.num_inference_steps=10",
    ]
    ccdp = ["--policy.type=ccdp", "--policy.failure_feature=primitive", "--policy.num_primitives=2"]
    runs = {
        "diffusion": ["--policy.type=diffusion"],
        "ccdp H=0": [*ccdp, "--policy.history_length=0"],
        "ccdp H=2": [*ccdp, "--policy.history_length=2"],
        "ccdp H=0, 3 stages": [*ccdp, "--policy.history_length=0", "--policy.vision_backbone_stages=3"],
    }
    results = {}
    for name, extra in runs.items():
        logger.info("(b') lerobot-train %s ...", name)
        results[name] = lerobot_train_speed(name, work / "train", [*common, *extra])
    base = results["diffusion"]["steps_per_s"]
    return {name: {**r, "ratio_step_time": base / r["steps_per_s"]} for name, r in results.items()}


def table(results: dict) -> str:
    lines = ["| measure | config | value | ratio CCDP / diffusion | target |", "|---|---|---|---|---|"]
    latency = results["latency"]
    for name, ms in latency["median_ms"].items():
        lines.append(
            f"| planning latency (ms, median) | {name} | {ms:.1f} | {latency['ratio'][name]:.2f}x | "
            f"{f'<= {LATENCY_TARGET}' if name == 'ccdp N=4' else ''} |"
        )
    train = results["train_step"]
    for name, ms in train["median_ms"].items():
        lines.append(
            f"| train step fwd+bwd+Adam (ms, median) | {name} | {ms:.0f} | {train['ratio'][name]:.2f}x | "
            f"{f'<= {TRAIN_TARGET}' if name.startswith('ccdp') else ''} |"
        )
    for size, r in results.get("render_sizes", {}).items():
        lines.append(
            f"| render size {size}x{size} | env step with camera / ccdp train step (3 stages) (ms) | "
            f"{r['env_step_ms']:.1f} / {r['train_step_ms']:.0f} | | |"
        )
    for name, r in results.get("lerobot_train", {}).items():
        lines.append(
            f"| lerobot-train s/step (update + data) | {name} | {1 / r['steps_per_s']:.3f} "
            f"({100 * r['data_s'] * r['steps_per_s']:.0f}% data) | {r['ratio_step_time']:.2f}x | |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=64, help="camera image height and width (pixels)")
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--train-steps", type=int, default=20)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--cli-steps", type=int, default=40)
    parser.add_argument("--cli-episodes", type=int, default=20)
    parser.add_argument("--no-cli", action="store_true")
    parser.add_argument(
        "--sizes", type=int, nargs="*", default=[48, 64, 96], help="render sizes for (c); none skips"
    )
    add_work_arguments(parser, "outputs/camera_cost", "bench_cameras.py")
    parser.add_argument("--out", type=Path, default=Path("outputs/camera_cost.json"))
    args = parser.parse_args(argv)
    init_logging()
    claim_work(args, CREATED_BY)
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    torch.set_num_threads(args.threads)
    results = {"command": command_line(f"python -m {CREATED_BY}", sys.argv[1:] if argv is None else argv)}
    logger.info("(a) planning latency ...")
    results["latency"] = planning_latency(args.size, args.repeats, args.warmup)
    logger.info("(b) training step ...")
    results["train_step"] = training_step_time(args.size, args.batch_size, args.train_steps, args.warmup)
    if args.sizes:
        logger.info("(c) render sizes ...")
        results["render_sizes"] = render_sizes(args.sizes, args.batch_size, args.train_steps, args.warmup)
    if not args.no_cli:
        from lerobot_ccdp.datasets.recipe_file import RecordRecipe
        from lerobot_ccdp.datasets.record import record_dataset

        pixels = {
            "obs_type": "pixels_agent_pos",
            "observation_width": args.size,
            "observation_height": args.size,
        }
        recipe = RecordRecipe(task=TASK, n_episodes=args.cli_episodes, seed=0, env_kwargs=pixels)
        root = recorded_once(
            args.work / "demos", lambda path: record_dataset(recipe, REPO_ID, path, progress=False)
        )
        results["lerobot_train"] = lerobot_train_runs(root, args.work, args.cli_steps, args.batch_size)
    results["table"] = table(results)
    return write_results(results, args.out)


if __name__ == "__main__":
    main()
