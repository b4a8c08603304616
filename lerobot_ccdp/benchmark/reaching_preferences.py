"""Failed share and preference error on a 2-D reaching task: does recovery keep the demonstrated preferences?

From the start state, a policy plans one chunk per row after the most preferred goal failed ("after 1") and
after the two most preferred goals failed ("after 2"), under torch.inference_mode() as LeRobot calls it:

    failed share       fraction of planned chunks heading to a failed goal
    ... on its path    of which those as near the failed goal's path as 95% of DP's chunks are to theirs: a
                       clean repeat; the rest of the failed share lies between that path and another
    preference error   total-variation distance between the method's shares over the remaining goals and DP's
                       own shares renormalised over them (same checkpoint, same start state), so the base's
                       own error does not count against the recovery

A chunk's goal is the goal whose demonstrated path from the start it lies nearest (`ReachingTask.option_of`),
not the policy's own labeller. `python -m lerobot_ccdp.benchmark.preference_family` runs it over the seeded
family of issue 17 and `tests/recovery/test_preferences.py` asserts the targets on two members.
"""

from typing import NamedTuple

import numpy as np
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.policies.factory import make_pre_post_processors

from lerobot_ccdp.benchmark.reaching2d import ReachingTask
from lerobot_ccdp.policy.modeling_ccdp import CCDPPolicy


class ExactStartClassifier(torch.nn.Module):
    """logit of P(a_0 repeats a failure in F | a_t) for the demonstrated chunks that start an episode,
    computed exactly: the noised demonstrations are a Gaussian mixture, one component per demonstrated start
    chunk c_j, so P(F | a_t) = sum_{j: z_j in F} N(a_t; sqrt(abar_t) c_j, 1 - abar_t) / sum_j N(...).

    Put in place of a trained failure-set classifier (same call signature), it isolates what the learnt
    classifier costs from what the base and the sampler cost: the reference row "CCDP, exact classifier" of
    the benchmark. It is a measurement device for the start state of the reaching family, not a policy: it
    ignores the state.
    """

    def __init__(self, policy: CCDPPolicy, preprocessor, dataset: LeRobotDataset):
        super().__init__()
        data = dataset.hf_dataset.select_columns(["action", "frame_index"]).with_format("numpy")[:]
        actions = np.stack(data["action"]).astype(np.float32)
        starts = np.flatnonzero(np.asarray(data["frame_index"]).reshape(-1) == 0)
        horizon = policy.config.horizon
        raw = torch.from_numpy(np.stack([actions[s : s + horizon] for s in starts]))
        self.chunks = preprocessor({"observation.state": torch.zeros(len(raw), 2), "action": raw})["action"]
        self.z = policy.model.feature.from_chunk(self.chunks, policy.model.outcomes)
        self.alphas_cumprod = policy.model.noise_scheduler.alphas_cumprod
        self.delta_z = policy.config.delta_z

    def forward(self, noisy, timestep, state, z, z_mask, keep_s=None):
        """Same inputs as `heads.classifier.FailureSetClassifier.forward`; logits (R,) of the exact
        mixture."""
        alpha_bar = self.alphas_cumprod[timestep].clone()[:, None]  # (R, 1)
        in_f = ((((self.z[None, :, None] - z[:, None]) ** 2).sum(-1) <= self.delta_z) & z_mask[:, None]).any(
            -1
        )
        log_w = (
            -((noisy[:, None] - alpha_bar.sqrt()[..., None, None] * self.chunks[None]) ** 2)
            .flatten(2)
            .sum(-1)
        )
        log_w = log_w / (2 * (1 - alpha_bar))  # (R, E)
        log_in = torch.logsumexp(log_w.masked_fill(~in_f, -1e9), dim=1)
        log_out = torch.logsumexp(log_w.masked_fill(in_f, -1e9), dim=1)
        return log_in - log_out


def failure_z(policy: CCDPPolicy, preprocessor, task: ReachingTask, goal: int, rows: int) -> torch.Tensor:
    """z of a failed reach to `goal` as the policy computes it: the goal's one-hot label, or where it
    ended."""
    if task.labelled:
        return policy.model.feature.one_hot(torch.full((rows,), goal))
    end = torch.from_numpy(task.goals[goal]).expand(rows, 2)
    return policy.model.feature.from_frame(
        preprocessor({"observation.state": end.clone()})["observation.state"]
    )


def planned_positions(
    policy: CCDPPolicy, pre, post, task: ReachingTask, failed: list[int], rows: int, seed: int
) -> np.ndarray:
    """Plan one chunk per row from the start after the failures `failed`; return its positions
    (rows, horizon, 2)."""
    torch.manual_seed(seed)
    batch = pre({"observation.state": torch.zeros(rows, 2)})
    with torch.inference_mode():
        policy.reset()
        policy.select_action(batch)
        for goal in failed:
            policy.report_failure(z=failure_z(policy, pre, task, goal, rows))
        policy.select_action(batch)  # re-plans the rows that failed; otherwise the first plan goes on
        chunks = (
            policy._rollout.memory.attempt_chunk.clone()
        )  # the whole planned chunk, not only its executed steps
    return post(chunks).reshape(rows, -1, 2).cpu().numpy()


def goal_shares(task: ReachingTask, positions: np.ndarray) -> np.ndarray:
    """Share of planned chunks heading to each goal."""
    return np.bincount(task.option_of(positions), minlength=len(task.goals)) / len(positions)


def on_path_tolerance(task: ReachingTask, positions: np.ndarray) -> float:
    """The squared distance to its own goal's path within which 95% of `positions` (R, T, 2) lie: how near a
    path DP's plans are."""
    return float(np.quantile(task.path_distances(positions).min(axis=1), 0.95))


def failed_on_path_share(
    task: ReachingTask, positions: np.ndarray, failed: list[int], tolerance: float
) -> float:
    """Share of planned chunks heading to a failed goal and within `tolerance` of its path: clean repeats of
    a failure, where the rest of the failed share is chunks between a failed goal's path and another."""
    distances = task.path_distances(positions)
    nearest = distances.argmin(axis=1)
    on_path = distances[np.arange(len(positions)), nearest] <= tolerance
    return float((np.isin(nearest, failed) & on_path).mean())


def scores(share: np.ndarray, reference: np.ndarray, failed: list[int]) -> tuple[float, float]:
    """(failed share, preference error against `reference` renormalised over the goals that did not fail)."""
    rest = np.setdiff1d(np.arange(len(share)), failed)
    kept, ref = share[rest], reference[rest]
    error = 0.5 * np.abs(kept / max(kept.sum(), 1e-9) - ref / max(ref.sum(), 1e-9)).sum()
    return float(share[failed].sum()), float(error)


def failure_sets(task: ReachingTask) -> dict[str, list[int]]:
    """The failures measured: the most preferred goal ("1"), then the two most preferred ("2")."""
    order = [int(g) for g in np.argsort(-task.preference)]
    return {"1": order[:1], "2": order[:2]}


def load(checkpoint, **fields) -> tuple[CCDPPolicy, object, object]:
    """The checkpoint's policy with config `fields` overridden, as lerobot-eval's --policy.<field> flags do,
    and its processors."""
    config = PreTrainedConfig.from_pretrained(checkpoint)
    for key, value in fields.items():
        setattr(config, key, value)
    policy = CCDPPolicy.from_pretrained(checkpoint, config=config).eval()
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    return policy, pre, post


class Method(NamedTuple):
    """A measured method: its recovery_mode and policy fields, and, for the exact-classifier reference, the
    demonstrations whose `ExactStartClassifier` replaces the checkpoint's classifier."""

    mode: str
    fields: dict
    exact_classifier_of: LeRobotDataset | None = None


def measure(task: ReachingTask, checkpoint, methods: dict[str, Method], rows: int) -> dict:
    """Every method's shares and scores after one and after two failures, on one checkpoint and the same
    seeds. DP's reference shares come from their own draw (seed 1), so DP measured against them (seed 2) shows
    the sampling noise of this measurement."""
    policy, pre, post = load(checkpoint, recovery_mode="dp")
    dp_plans = planned_positions(policy, pre, post, task, [], rows, seed=1)
    reference, tolerance = goal_shares(task, dp_plans), on_path_tolerance(task, dp_plans)
    result = {
        "goals": len(task.goals),
        "labelled": task.labelled,
        "dp_shares": reference.tolist(),
        "methods": {},
        "positions": {},
    }
    for name, method in methods.items():
        policy, pre, post = load(checkpoint, recovery_mode=method.mode, **method.fields)
        if method.exact_classifier_of is not None:
            policy.model.recovery = ExactStartClassifier(policy, pre, method.exact_classifier_of)
        for count, failed in failure_sets(task).items():
            planned = planned_positions(policy, pre, post, task, failed, rows, seed=2)
            share = goal_shares(task, planned)
            failed_share, error = scores(share, reference, failed)
            result["methods"].setdefault(name, {})[count] = {
                "failed": failed,
                "shares": share.tolist(),
                "failed_share": failed_share,
                "failed_on_path_share": failed_on_path_share(task, planned, failed, tolerance),
                "preference_error": error,
            }
            result["positions"][f"{name}|{count}"] = planned[:64].tolist()
    return result
