"""``sqpmpc metrics RUN_DIR``: metrics, plots and recording of a run folder from its record.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from sqpmpc.io.files import write_run
from sqpmpc.io.runlog import RECORD_FILE, RecordError, read_record

__all__ = ["add_parser", "main"]



# ---------------------------------------------------------------- sqpmpc metrics RUN_DIR
def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``metrics RUN_DIR`` to the ``sqpmpc`` subcommands; returns its parser."""
    parser = subparsers.add_parser(
        "metrics", help="recompute metrics.json and trajectory.npz of a run folder from its "
                        f"incremental record ({RECORD_FILE}; e.g. after the plant was killed)")
    parser.add_argument("run_dir", type=Path, help="the run's output folder")
    parser.add_argument("--plots", action="store_true", help="draw the PNG plots too")
    parser.set_defaults(handler=main)
    return parser


def main(args: argparse.Namespace) -> int:
    """Handle ``sqpmpc metrics``: 0 written, 2 no readable record."""
    try:
        record = read_record(args.run_dir)
    except RecordError as exc:
        print(f"sqpmpc metrics: error: {exc}", file=sys.stderr)
        return 2
    out = args.run_dir if args.run_dir.is_dir() else args.run_dir.parent
    metrics = write_run(out, record, plots=args.plots)
    print(f"{out}: {metrics['steps']} samples of {record.scenario.steps} "
          f"(completed: {record.completed}, recovered: {record.extra['recovered_from_record']}),"
          f" min clearance {metrics['min_clearance']:.4g} m, collisions {metrics['collisions']}")
    return 0
