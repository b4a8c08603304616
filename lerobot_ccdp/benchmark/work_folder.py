"""The scratch folder of a measuring tool (`--work`): its flags, and claiming it before anything is written.

The tools delete and rewrite what they made under `--work`, so they write only into a folder they made
(`lerobot_ccdp.datasets.ownership`); `--adopt` takes over one made by an earlier version of the tool (its
script in `benchmarks/` before 0032ef5, or a folder from before the ownership markers).
"""

import argparse
import sys
from pathlib import Path

from lerobot_ccdp.datasets.ownership import NotOwned, claim_output_folder


def add_work_arguments(parser: argparse.ArgumentParser, default: str, old_script: str) -> None:
    """`--work` (default `default`) and `--adopt` for the tool that was `benchmarks/<old_script>`."""
    parser.add_argument("--work", type=Path, default=Path(default))
    parser.add_argument(
        "--adopt",
        action="store_true",
        help=f"take over a --work made by an earlier version of this tool (benchmarks/{old_script}, "
        "or before ownership markers)",
    )


def claim_work(args: argparse.Namespace, created_by: str) -> None:
    """Make `args.work` the tool's, or exit with the one-line reason nothing was written."""
    try:
        claim_output_folder(args.work, created_by, adopt=args.adopt, flag="--work")
    except NotOwned as error:
        sys.exit(str(error))
