"""Start-up cost of the plugin: wall time of `lerobot-train --help` with and without LeRobot discovering it.

    HF_HUB_OFFLINE=1 .venv/bin/python benchmarks/bench_import.py [--runs 5] [--script lerobot_train]

LeRobot's CLIs import every installed `lerobot_policy_*` distribution (`register_third_party_plugins`), so
every `lerobot-*` command pays for importing this package. Both variants run the same launcher in a fresh
interpreter; "without" hides this package's distribution from `importlib.metadata.distributions`, so LeRobot's
discovery scan and everything else is identical apart from importing the plugin. Runs alternate so background
load hits both alike; CPU seconds (the child's user + system time) are less sensitive to other load on the
machine than wall seconds. Beyond the import (the discovery figure), a registered `ccdp` also makes draccus
render its fields in `--help`, so the help text's length is printed too. Prints the medians of each and
whether the plugin, MuJoCo and lerobot_eval were loaded when the CLI exited.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import subprocess
import sys
import time

DISTRIBUTION = "lerobot_policy_ccdp"
LAUNCHER = f"""
import importlib, importlib.metadata, json, sys, time
variant, script = sys.argv[1:]
if variant == "without":
    everything = importlib.metadata.distributions
    importlib.metadata.distributions = lambda **kw: (
        d for d in everything(**kw) if d.metadata.get("Name") != {DISTRIBUTION!r}
    )
sys.argv = [script, "--help"]
cli = importlib.import_module(f"lerobot.scripts.{{script}}")
discover, discovery = cli.register_third_party_plugins, []
def timed_discovery():
    start = time.process_time()
    discover()
    discovery.append(time.process_time() - start)
cli.register_third_party_plugins = timed_discovery
try:
    cli.main()
except SystemExit:
    pass
loaded = [m for m in ("lerobot_policy_ccdp", "mujoco", "lerobot.scripts.lerobot_eval") if m in sys.modules]
print(json.dumps({{"discovery": sum(discovery), "loaded": loaded}}), file=sys.stderr)
"""


def run_once(variant: str, script: str) -> dict:
    """One fresh interpreter running `<script> --help`: its wall and CPU seconds, the CPU seconds of LeRobot's
    plugin discovery in it, and the watched modules it had loaded."""
    before, start = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-c", LAUNCHER, variant, script], check=False, capture_output=True, text=True
    )
    wall, after = time.perf_counter() - start, resource.getrusage(resource.RUSAGE_CHILDREN)
    if result.returncode != 0:
        raise RuntimeError(result.stderr)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    report = json.loads(result.stderr.strip().splitlines()[-1])
    return {"wall": wall, "cpu": cpu, "help_chars": len(result.stdout), **report}


def cpu_model() -> str:
    """The `lscpu` model name (platform.processor() is empty on most Linux builds)."""
    try:
        out = subprocess.run(["lscpu"], check=False, capture_output=True, text=True).stdout
    except FileNotFoundError:
        return platform.processor() or platform.machine()
    return next(
        (line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name")), "?"
    )


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--script", default="lerobot_train", help="module under lerobot.scripts")
    args = parser.parse_args(argv)

    run_once("with", args.script)  # warm the file cache so the first measured run is not an outlier
    runs: dict[str, list[dict]] = {"with": [], "without": []}
    for _ in range(args.runs):
        for variant, reports in runs.items():
            reports.append(run_once(variant, args.script))

    cli = args.script.replace("_", "-")
    print(
        f"`{cli} --help`, {args.runs} alternated runs each, CPU {cpu_model()}, "
        f"Python {platform.python_version()}"
    )
    medians = {
        variant: {key: statistics.median(r[key] for r in reports) for key in ("wall", "cpu", "discovery")}
        for variant, reports in runs.items()
    }
    for variant, median in medians.items():
        print(
            f"  {variant:>7} plugin: median wall {median['wall']:.2f} s, CPU {median['cpu']:.2f} s, "
            f"plugin discovery CPU {median['discovery']:.3f} s, "
            f"--help {runs[variant][-1]['help_chars']} chars; "
            f"loaded at exit: "
            f"{', '.join(runs[variant][-1]['loaded']) or 'none of the watched modules'}"
        )
    extra = {key: medians["with"][key] - medians["without"][key] for key in ("wall", "cpu", "discovery")}
    print(
        f"  the plugin adds (difference of medians): wall {extra['wall']:+.2f} s, CPU {extra['cpu']:+.2f} s, "
        f"discovery CPU {extra['discovery']:+.3f} s"
    )
    return {"runs": runs, "medians": medians}


if __name__ == "__main__":
    main()
