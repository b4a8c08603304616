"""Does recovery keep the demonstrated preferences? A seeded family of 2-D reaching tasks (issue 17).

    HF_HUB_OFFLINE=1 .venv/bin/python benchmarks/bench_preferences.py [--members 0 1 ... 11] [--out outputs/preferences]

Each family member (`ReachingTask.family_member(seed)`: 3 to 6 goals at random angles, random preferences, bent
paths; even seeds carry `primitive` labels, odd seeds do not and use `final_state` z) is recorded as a LeRobot
dataset, its base is trained with lerobot-train, and each recovery form is trained from that base with lerobot-train
as a user would. From the start state, 512 chunks are planned under torch.inference_mode() after the most preferred
goal failed, and after the two most preferred goals failed, with every method on the same checkpoint and seeds:

    failed share       fraction of planned chunks heading to a failed goal
    preference error   total-variation distance between the method's shares over the remaining goals and DP's own
                       shares renormalised over them (same checkpoint, same start state), so the base's own error
                       does not count against the recovery

A chunk's goal is the goal whose demonstrated path from the start it lies nearest (`ReachingTask.option_of`), not the
policy's own labeller. Methods: DP, DP* (32 candidates x 4 rounds, as tuned in docs/benchmarks.md) and CCDP with the
failure-set classifier (`--policy.recovery_head=classifier`, w_z = 1). Prints the table, writes `preferences.md`,
`results.json` and a Fig. 2-style panel grid `preferences.png` under --out. Stages whose inputs did not change are
skipped (stamps, as in the pipeline); --members 100 101 ... are the development members the settings were chosen on.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from lerobot_ccdp.reaching2d import ReachingTask
from lerobot_ccdp.stage_stamps import StampBook, stamp

BIN = Path(sys.executable).parent
CHECKPOINT = Path("checkpoints/last/pretrained_model")
# method -> (recovery_mode, policy fields set for the measurement)
METHODS = {
    "DP": ("dp", {}),
    "DP*": ("dp_star", {"dp_star_candidates": 32, "dp_star_rounds": 4}),
    "CCDP classifier": ("ccdp", {}),
}


def train(name: str, out: Path, args: list[str], upstream: str | None, book: StampBook) -> tuple[Path, str]:
    """lerobot-train into `out` unless the checkpoint there was made by the same command from the same upstream."""
    command = ["lerobot-train", *args, f"--output_dir={out}", "--policy.push_to_hub=false", "--num_workers=0",
               "--wandb.enable=false", "--log_freq=500", "--seed=0"]
    value = stamp(command, upstream)
    if (out / CHECKPOINT / "model.safetensors").exists() and book.matches(name, value):
        return out / CHECKPOINT, value
    shutil.rmtree(out, ignore_errors=True)
    print(f"  {name}: lerobot-train into {out}", flush=True)
    log = out.with_suffix(".log")
    with log.open("w") as handle:
        done = subprocess.run([str(BIN / command[0]), *command[1:]], stdout=handle, stderr=subprocess.STDOUT)
    if done.returncode:
        raise RuntimeError(f"{name} failed (exit {done.returncode}); see {log}")
    book.record(name, value)
    return out / CHECKPOINT, value


def prepare_member(seed: int, out: Path, base_steps: int, head_steps: int, episodes: int) -> Path:
    """Record member `seed`, train its base and its classifier head; return the head's checkpoint."""
    task = ReachingTask.family_member(seed)
    root = out / f"member_{seed}"
    root.mkdir(parents=True, exist_ok=True)
    book = StampBook(root / "stamps.json")
    data, repo = root / "data", f"local/reaching_family_{seed}"
    data_stamp = stamp(["record", f"--seed={seed}", f"--episodes={episodes}"], None)
    if not (data / "meta" / "info.json").exists() or not book.matches("record", data_stamp):
        shutil.rmtree(data, ignore_errors=True)
        task.record(data, repo, episodes, seed)
        book.record("record", data_stamp)
    z = (["--policy.failure_feature=primitive", f"--policy.num_primitives={len(task.goals)}"] if task.labelled
         else ["--policy.failure_feature=final_state"])
    dataset = [f"--dataset.repo_id={repo}", f"--dataset.root={data}"]
    base, base_stamp = train("base", root / "base", ["--policy.type=ccdp", *z, *dataset, f"--steps={base_steps}",
                                                     "--batch_size=64", f"--save_freq={base_steps}"], data_stamp, book)
    head, _ = train("classifier", root / "classifier", [
        f"--policy.path={base}", "--policy.training_stage=recovery", "--policy.recovery_head=classifier", *dataset,
        f"--steps={head_steps}", "--batch_size=64", f"--save_freq={head_steps}"], base_stamp, book)
    return head


def failure_z(policy, preprocessor, task: ReachingTask, goal: int, rows: int) -> torch.Tensor:
    """z of a failed reach to `goal` as the policy computes it: the goal's one-hot label, or where it ended."""
    if task.labelled:
        return policy.feature.one_hot(torch.full((rows,), goal))
    end = torch.from_numpy(task.goals[goal]).expand(rows, 2)
    return policy.feature.from_frame(preprocessor({"observation.state": end.clone()})["observation.state"])


def planned_goals(policy, pre, post, task: ReachingTask, failed: list[int], rows: int, seed: int) -> np.ndarray:
    """Plan one chunk per row from the start after the failures `failed`, as LeRobot calls a policy (under
    torch.inference_mode()); return the positions (rows, horizon, 2)."""
    torch.manual_seed(seed)
    batch = pre({"observation.state": torch.zeros(rows, 2)})
    with torch.inference_mode():
        policy.reset()
        policy.select_action(batch)
        for goal in failed:
            policy.report_failure(z=failure_z(policy, pre, task, goal, rows))
        policy.select_action(batch)
        chunks = policy._memory.attempt_chunk.clone()
    return post(chunks).reshape(rows, -1, 2).cpu().numpy()


def shares(task: ReachingTask, positions: np.ndarray) -> np.ndarray:
    return np.bincount(task.option_of(positions), minlength=len(task.goals)) / len(positions)


def scores(share: np.ndarray, reference: np.ndarray, failed: list[int]) -> tuple[float, float]:
    """(failed share, preference error against `reference` renormalised over the goals that did not fail)."""
    rest = np.setdiff1d(np.arange(len(share)), failed)
    kept, ref = share[rest], reference[rest]
    error = 0.5 * np.abs(kept / max(kept.sum(), 1e-9) - ref / max(ref.sum(), 1e-9)).sum()
    return float(share[failed].sum()), float(error)


def measure_member(seed: int, checkpoint: Path, rows: int) -> dict:
    """Every method's shares after one and after two failures, and the scores, on one member's checkpoint."""
    from lerobot.policies.factory import make_pre_post_processors

    from lerobot_ccdp.modeling_ccdp import CCDPPolicy

    task = ReachingTask.family_member(seed)
    policy = CCDPPolicy.from_pretrained(checkpoint).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    order = list(np.argsort(-task.preference))
    failure_sets = {"1": [int(order[0])], "2": [int(order[0]), int(order[1])]}
    policy.config.recovery_mode = "dp"
    reference = shares(task, planned_goals(policy, pre, post, task, [], rows, seed=1))
    result = {"goals": len(task.goals), "labelled": task.labelled, "dp_shares": reference.tolist(), "methods": {}}
    positions = {}
    for name, (mode, fields) in METHODS.items():
        policy.config.recovery_mode = mode
        for key, value in fields.items():
            setattr(policy.config, key, value)
        for count, failed in failure_sets.items():
            started = time.perf_counter()
            planned = planned_goals(policy, pre, post, task, failed, rows, seed=2)
            share = shares(task, planned)
            failed_share, error = scores(share, reference, failed)
            result["methods"].setdefault(name, {})[count] = {
                "failed": failed, "shares": share.tolist(), "failed_share": failed_share,
                "preference_error": error, "seconds": time.perf_counter() - started}
            positions[(name, count)] = planned[:64]
    result["positions"] = {f"{name}|{count}": p.tolist() for (name, count), p in positions.items()}
    return result


def table(results: dict[int, dict]) -> str:
    """Markdown: per member and on average, failed share / preference error after 1 and 2 failures."""
    names = list(METHODS)
    head = "| member | goals | z | " + " | ".join(f"{n} after 1 | {n} after 2" for n in names) + " |"
    lines = [head, "|" + "---|" * (3 + 2 * len(names))]
    cells = {(n, c): [] for n in names for c in "12"}
    for seed, r in sorted(results.items()):
        row = [str(seed), str(r["goals"]), "primitive" if r["labelled"] else "final_state"]
        for n in names:
            for c in "12":
                m = r["methods"][n][c]
                cells[(n, c)].append((m["failed_share"], m["preference_error"]))
                row.append(f"{m['failed_share']:.3f} / {m['preference_error']:.3f}")
        lines.append("| " + " | ".join(row) + " |")
    for label, reduce in (("mean", np.mean), ("worst", np.max)):
        row = [f"**{label}**", "", ""]
        for n in names:
            for c in "12":
                values = np.array(cells[(n, c)])
                row.append(f"{reduce(values[:, 0]):.3f} / {reduce(values[:, 1]):.3f}")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def panel_grid(results: dict[int, dict], path: Path) -> None:
    """Fig. 2-style panels: per member, 64 planned chunks of DP, and of DP* and CCDP after one and two failures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = [("DP", "1", "DP (no memory)"), ("DP*", "1", "DP* after 1"), ("CCDP classifier", "1", "CCDP after 1"),
               ("DP*", "2", "DP* after 2"), ("CCDP classifier", "2", "CCDP after 2")]
    fig, axes = plt.subplots(len(results), len(columns), figsize=(2.2 * len(columns), 2.2 * len(results)),
                             squeeze=False)
    colours = plt.get_cmap("tab10")
    for row, (seed, r) in enumerate(sorted(results.items())):
        task = ReachingTask.family_member(seed)
        for col, (name, count, title) in enumerate(columns):
            ax = axes[row, col]
            planned = np.array(r["positions"][f"{name}|{count}"])
            for chunk, goal in zip(planned, task.option_of(planned), strict=True):
                ax.plot(chunk[:, 0], chunk[:, 1], color=colours(goal % 10), lw=0.6, alpha=0.6)
            failed = r["methods"][name][count]["failed"] if name != "DP" else []
            for g, (x, y) in enumerate(task.goals):
                ax.scatter([x], [y], s=20 + 200 * task.preference[g], color=colours(g % 10),
                           marker="x" if g in failed else "o")
            ax.set_xlim(-1.3, 1.3), ax.set_ylim(-1.3, 1.3), ax.set_xticks([]), ax.set_yticks([])
            if row == 0:
                ax.set_title(title, fontsize=8)
            if col == 0:
                ax.set_ylabel(f"member {seed}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--members", type=int, nargs="+", default=list(range(12)))
    parser.add_argument("--out", type=Path, default=Path("outputs/preferences"))
    parser.add_argument("--base-steps", type=int, default=1000)
    parser.add_argument("--head-steps", type=int, default=3000)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--rows", type=int, default=512)
    parser.add_argument("--report-only", action="store_true", help="tabulate the members already measured")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    results_path = args.out / "results.json"
    results = {int(k): v for k, v in json.loads(results_path.read_text()).items()} if results_path.exists() else {}
    if args.report_only:
        args.members = [seed for seed in args.members if seed in results]
    for seed in [] if args.report_only else args.members:
        started = time.perf_counter()
        task = ReachingTask.family_member(seed)
        print(f"member {seed}: {len(task.goals)} goals, preference {np.round(task.preference, 2).tolist()}, bend "
              f"{task.bend:.2f}, z {'primitive' if task.labelled else 'final_state'}", flush=True)
        checkpoint = prepare_member(seed, args.out, args.base_steps, args.head_steps, args.episodes)
        results[seed] = measure_member(seed, checkpoint, args.rows)
        results_path.write_text(json.dumps(results))
        print(f"member {seed} done in {time.perf_counter() - started:.0f} s", flush=True)
    chosen = {seed: results[seed] for seed in args.members}
    text = table(chosen)
    print(text)
    (args.out / "preferences.md").write_text(
        f"Failed share / preference error; members {args.members}, {args.rows} chunks each, base {args.base_steps} "
        f"steps, classifier {args.head_steps} steps.\n\n{text}\n")
    panel_grid(chosen, args.out / "preferences.png")


if __name__ == "__main__":
    main()
