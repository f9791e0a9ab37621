"""``sqpmpc metrics RUN_DIR``: metrics, plots and recording of a run folder from its record.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from sqpmpc.io.files import write_run
from sqpmpc.io.reporting import missed_goal, summarize
from sqpmpc.io.runlog import RECORD_FILE, RecordError, read_record

__all__ = ["add_parser", "main"]


# ---------------------------------------------------------------- sqpmpc metrics RUN_DIR
def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add ``metrics RUN_DIR`` to the ``sqpmpc`` subcommands; returns its parser."""
    parser = subparsers.add_parser(
        "metrics", help="recompute metrics.json and trajectory.npz of any run folder "
                        "(sqpmpc run, launch, plant, RunRecorder) from its record "
                        f"({RECORD_FILE}; e.g. after the plant was killed) and summarize it")
    parser.add_argument("run_dir", type=Path, help="the run's output folder")
    parser.add_argument("--plots", action="store_true", help="draw the PNG plots too")
    parser.add_argument("--fail-on-miss", action="store_true",
                        help="exit with status 4 when a robot did not arrive, a collision "
                             "happened or the run did not complete")
    parser.set_defaults(handler=main)
    return parser


def main(args: argparse.Namespace) -> int:
    """Handle ``sqpmpc metrics``: 0 written, 2 no readable record, 4 with ``--fail-on-miss``
    when the run missed its goal (:func:`sqpmpc.io.reporting.missed_goal`)."""
    try:
        record = read_record(args.run_dir)
    except RecordError as exc:
        print(f"sqpmpc metrics: error: {exc}", file=sys.stderr)
        return 2
    out = args.run_dir if args.run_dir.is_dir() else args.run_dir.parent
    # a recording.mcap written by the run has the plans, which the record does not keep
    metrics = write_run(out, record, plots=args.plots,
                        recording=not (out / "recording.mcap").is_file())
    print(summarize(metrics))
    print(f"wrote {out} (recovered from the record alone: "
          f"{record.extra['recovered_from_record']})")
    miss = missed_goal(metrics)
    if args.fail_on_miss and miss:
        print(f"sqpmpc metrics: goal missed: {miss}", file=sys.stderr)
        return 4
    return 0
