"""Start-up cost of the plugin: wall time of `lerobot-train --help` with and without LeRobot discovering it.

    HF_HUB_OFFLINE=1 .venv/bin/python benchmarks/bench_import.py [--runs 5] [--script lerobot_train]

LeRobot's CLIs import every installed `lerobot_policy_*` distribution (`register_third_party_plugins`), so
every `lerobot-*` command pays for importing this package. Both variants run the same launcher in a fresh
interpreter; "without" hides this package's distribution from `importlib.metadata.distributions`, so LeRobot's
discovery scan and everything else is identical apart from importing the plugin. Runs alternate so background
load hits both alike. Prints the median and minimum of each and whether the plugin, MuJoCo and lerobot_eval
were loaded when the CLI exited.
"""

from __future__ import annotations

import argparse
import json
import platform
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
    start = time.perf_counter()
    discover()
    discovery.append(time.perf_counter() - start)
cli.register_third_party_plugins = timed_discovery
try:
    cli.main()
except SystemExit:
    pass
loaded = [m for m in ("lerobot_policy_ccdp", "mujoco", "lerobot.scripts.lerobot_eval") if m in sys.modules]
print(json.dumps({{"discovery": sum(discovery), "loaded": loaded}}), file=sys.stderr)
"""


def run_once(variant: str, script: str) -> tuple[float, dict]:
    """Wall time of one fresh interpreter running `<script> --help`; its discovery time and loaded modules."""
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-c", LAUNCHER, variant, script], check=False, capture_output=True,
                            text=True)
    elapsed = time.perf_counter() - start
    if result.returncode != 0:
        raise RuntimeError(result.stderr)
    return elapsed, json.loads(result.stderr.strip().splitlines()[-1])


def cpu_model() -> str:
    """The `lscpu` model name (platform.processor() is empty on most Linux builds)."""
    try:
        out = subprocess.run(["lscpu"], check=False, capture_output=True, text=True).stdout
    except FileNotFoundError:
        return platform.processor() or platform.machine()
    return next((line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name")), "?")


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--script", default="lerobot_train", help="module under lerobot.scripts")
    args = parser.parse_args(argv)

    run_once("with", args.script)  # warm the file cache so the first measured run is not an outlier
    runs: dict[str, list[tuple[float, dict]]] = {"with": [], "without": []}
    for _ in range(args.runs):
        for variant, results in runs.items():
            results.append(run_once(variant, args.script))

    cli = args.script.replace("_", "-")
    print(f"`{cli} --help`, {args.runs} alternated runs each, CPU {cpu_model()}, Python {platform.python_version()}")
    summary = {}
    for variant, results in runs.items():
        wall = [elapsed for elapsed, _ in results]
        discovery = [report["discovery"] for _, report in results]
        summary[variant] = {"wall": wall, "discovery": discovery, "loaded": results[-1][1]["loaded"]}
        print(f"  {variant:>7} plugin: wall median {statistics.median(wall):.2f} s (min {min(wall):.2f}), "
              f"plugin discovery median {statistics.median(discovery):.3f} s; "
              f"loaded at exit: {', '.join(results[-1][1]['loaded']) or 'none of the watched modules'}")
    extra = statistics.median(summary["with"]["discovery"]) - statistics.median(summary["without"]["discovery"])
    print(f"  importing the plugin costs {extra:+.3f} s (difference of the discovery medians)")
    return summary


if __name__ == "__main__":
    main()
