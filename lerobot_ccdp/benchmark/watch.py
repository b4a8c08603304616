"""`python -m lerobot_ccdp.benchmark.watch`: a GIF of DP repeating a failed option beside CCDP recovering, on
one seed.

It reads what `lerobot-eval` already wrote for two methods evaluated on the same seeds (the pipeline's
rendered runs, `<task>/videos/<method>/`): the per-episode outcomes in `eval_info.json` and the videos of the
first rendered episodes (`videos/**/eval_episode_<i>.mp4`, episode i of both runs has the same seed). Without
`--episode` it picks the rendered episode where DP repeated a failure most while CCDP succeeded after a
failure.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import av
import numpy as np
from lerobot.utils.utils import init_logging
from PIL import Image, ImageDraw

from lerobot_ccdp.benchmark.episodes import Episodes

logger = logging.getLogger(__name__)


def rendered_videos(eval_dir: Path) -> dict[int, Path]:
    """Episode index -> video lerobot-eval rendered for it (LeRobot renders the first episodes only)."""
    videos = {int(p.stem.rsplit("_", 1)[1]): p for p in eval_dir.glob("videos/**/eval_episode_*.mp4")}
    if not videos:
        raise FileNotFoundError(
            f"{eval_dir} holds no videos: evaluate with a rendering env (`--env.render_mode=rgb_array`, "
            "the eval configs' setting) so lerobot-eval saves its first episodes as videos."
        )
    return videos


def pick_episode(baseline: Episodes, recovering: Episodes, candidates: list[int]) -> int:
    """The rendered episode that shows recovery best: the baseline repeats a failure (most repeats first) and
    the recovering method succeeds after at least one failure."""
    shown = [
        i
        for i in candidates
        if baseline.repeated_failures[i] > 0
        and recovering.success[i]
        and recovering.attempts_after_failure[i] > 0
    ]
    if not shown:
        raise ValueError(
            f"No rendered episode ({candidates}) where the baseline repeated a failure and the other method "
            "recovered from one; pass --episode N to show one anyway, or evaluate more seeds."
        )
    return max(shown, key=lambda i: (int(baseline.repeated_failures[i]), -i))


def frames(video: Path) -> list[np.ndarray]:
    """Every frame of a video as an RGB array."""
    with av.open(str(video)) as container:
        return [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]


def labelled(frame: np.ndarray, text: str) -> Image.Image:
    """The frame with `text` on a dark band above it."""
    band = 14
    canvas = Image.new("RGB", (frame.shape[1], frame.shape[0] + band), (20, 20, 20))
    canvas.paste(Image.fromarray(frame), (0, band))
    ImageDraw.Draw(canvas).text((3, 1), text, fill=(255, 255, 255))
    return canvas


def side_by_side(
    left: list[np.ndarray], right: list[np.ndarray], titles: tuple[str, str], every: int
) -> list[Image.Image]:
    """Paired frames, the shorter episode holding its last frame, every `every`-th frame kept."""
    length = max(len(left), len(right))
    out = []
    for t in range(0, length, every):
        panels = [
            labelled(v[min(t, len(v) - 1)], title) for v, title in zip((left, right), titles, strict=True)
        ]
        canvas = Image.new("RGB", (panels[0].width + panels[1].width + 4, panels[0].height), (255, 255, 255))
        canvas.paste(panels[0], (0, 0))
        canvas.paste(panels[1], (panels[0].width + 4, 0))
        out.append(canvas)
    return out


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


def write_gif(images: list[Image.Image], path: Path, fps: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(
        path, save_all=True, append_images=images[1:], duration=int(1000 / fps), loop=0, optimize=True
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--eval-root",
        type=Path,
        required=True,
        help="a folder holding one lerobot-eval output folder per method, e.g. the pipeline's "
        "outputs/quickstart/DoorOpening-v0/door_opening/videos",
    )
    parser.add_argument("--out", type=Path, required=True, help="GIF to write, e.g. docs/watch_door.gif")
    parser.add_argument("--methods", nargs=2, default=["dp", "ccdp"], metavar=("BASELINE", "RECOVERING"))
    parser.add_argument(
        "--episode", type=int, default=None, help="rendered episode to show (default: picked)"
    )
    parser.add_argument("--every", type=int, default=2, help="keep every n-th frame (a smaller GIF)")
    parser.add_argument("--fps", type=float, default=10.0, help="GIF frame rate (the tasks run at 10 Hz)")
    args = parser.parse_args(argv)
    init_logging()
    dirs = [args.eval_root / m for m in args.methods]
    outcomes = [Episodes.from_eval_info(d / "eval_info.json") for d in dirs]
    videos = [rendered_videos(d) for d in dirs]
    common = sorted(set(videos[0]) & set(videos[1]))
    episode = pick_episode(*outcomes, common) if args.episode is None else args.episode
    if episode not in common:
        raise SystemExit(f"Episode {episode} was not rendered for both methods; rendered: {common}")
    titles = tuple(
        f"{m.upper()}: {_count(o.repeated_failures[episode], 'repeat')}, "
        f"{'success' if o.success[episode] else 'failed'}"
        for m, o in zip(args.methods, outcomes, strict=True)
    )
    images = side_by_side(frames(videos[0][episode]), frames(videos[1][episode]), titles, args.every)
    write_gif(images, args.out, args.fps / args.every)
    logger.info("Wrote %s: episode %d (%d frames); %s | %s", args.out, episode, len(images), *titles)


if __name__ == "__main__":
    main()
