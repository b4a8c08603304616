"""Where each demonstrated option ends, so a demonstrated chunk's `final_state` z is the state its option
reaches.

The paper reads z at the end of a primitive (III-B.1). Labels mark primitives directly. Without labels, the
end of an option is found in the demonstrator's own commands, after the keyframe heuristic of James & Davison
(2022, Q-attention: a keyframe where the gripper changes state or the arm stops):
- `releases`: an option ends where the gripper lets go (pick and place: which crate the object went into);
- `drops`: the same, but the option keeps the opening command and the frames after it while the arm holds
  still (the fingers opening, the object falling), as a demonstrator's labels do;
- `pauses`: an option ends where the commanded action holds still (a pour over a cup, a press of a button).
A segment never crosses an episode's end, and every episode's last frame ends one.
"""

import numpy as np

from lerobot_ccdp.policy.outcome_index import episode_bounds

SEGMENT_RULES = ("labels", "releases", "drops", "pauses")


def segment_ends(
    rule: str,
    episode_index: np.ndarray,
    actions: np.ndarray,
    labels: np.ndarray | None = None,
    gripper_dim: int = -1,
    pause_steps: int = 2,
    pause_tolerance: float = 1e-3,
) -> np.ndarray:
    """Boolean per frame (frames sorted by episode): True where a segment ends under `rule`.

    `labels`: runs of one label (the whole episode without labels). `releases`: the last frame before the
    gripper command (`actions[:, gripper_dim]`) crosses the middle of its demonstrated range back to the side
    it held at its episode's first frame, i.e. each release of a hand that starts open. `drops`: each
    release's end moved on to the opening frame and the still frames right after it. `pauses`: the last frame
    of each run of at least `pause_steps` frames whose action moved less than `pause_tolerance` (largest
    change of any dim) since the frame before.
    """
    if rule not in SEGMENT_RULES:
        raise ValueError(f"Unknown segment rule {rule!r}; choose one of {list(SEGMENT_RULES)}.")
    n = len(episode_index)
    ends = np.ones(n, dtype=bool)
    same_episode = episode_index[1:] == episode_index[:-1]
    ends[:-1] = ~same_episode
    if rule == "labels":
        if labels is not None:
            labels = np.asarray(labels).reshape(n)
            ends[:-1] |= labels[1:] != labels[:-1]
        return ends
    still = np.zeros(n, dtype=bool)
    still[1:] = same_episode & (np.abs(np.diff(actions, axis=0)).max(axis=1) < pause_tolerance)
    if rule in ("releases", "drops"):
        gripper = actions[:, gripper_dim]
        closed_side = gripper > (gripper.min() + gripper.max()) / 2
        # off the side its episode began on
        away = closed_side != closed_side[episode_bounds(episode_index)[0]]
        releases = np.flatnonzero(away[:-1] & ~away[1:] & same_episode)
        # from the opening command (same episode) to the frame before the next non-still one
        if rule == "drops":
            moves = np.flatnonzero(~np.append(still, False))
            releases = moves[np.searchsorted(moves, releases + 2)] - 1
        ends[releases] = True
        return ends
    run = np.zeros(n, dtype=np.int64)  # length of the still run ending at each frame
    for t in np.flatnonzero(still):
        run[t] = run[t - 1] + 1
    last_of_run = still & np.concatenate([~still[1:], [True]])
    ends |= last_of_run & (run >= pause_steps)
    return ends


def segment_final_states(states: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """The state each frame's option reaches: `states` at the first segment end at or after the frame."""
    end_frames = np.flatnonzero(ends)
    return states[end_frames[np.searchsorted(end_frames, np.arange(len(states)))]]
