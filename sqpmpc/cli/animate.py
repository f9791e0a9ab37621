"""``sqpmpc animate RUN_DIR``: the command of :mod:`sqpmpc.io.animate`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from sqpmpc.cli.options import nonnegative_int, positive_float, positive_int
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.io.animate import MAX_FRAMES, animate, load_run, write_frame

__all__ = ["EVERY", "Progress", "add_parser", "main"]

EVERY = 2.0
"""Seconds between two progress lines while the frames are drawn."""


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add ``animate`` to the ``sqpmpc`` sub-commands (handler: :func:`main`)."""
    p = subparsers.add_parser("animate", help="write an animation (GIF, MP4) of a run folder",
                              description=__doc__.splitlines()[0])
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a run's output folder")
    p.add_argument("--out", type=Path, default=None,
                   help="file to write, .gif (default RUN_DIR/animation.gif) or .mp4")
    p.add_argument("--fps", type=positive_float, default=10.0,
                   help="frames per second (default 10)")
    p.add_argument("--step", type=positive_int, default=None,
                   help=f"samples per frame (default: at most {MAX_FRAMES} frames)")
    p.add_argument("--frame", type=nonnegative_int, default=None, metavar="K",
                   help="write only the frame of sample K as a PNG (--out, default "
                        "RUN_DIR/frame-K.png)")
    p.add_argument("--scenario", default=None,
                   help="the run's scenario (file or built-in name), for run folders "
                        "written without diameters")
    p.set_defaults(handler=main)
    return p


class Progress:
    """Prints ``drawn N/M frames, S s`` at most every :data:`EVERY` seconds, and the first
    frame's line (drawing a long run's frames takes minutes)."""

    def __init__(self) -> None:
        self.t0 = time.perf_counter()
        self.shown: float | None = None

    def __call__(self, done: int, total: int) -> None:
        now = time.perf_counter()
        if self.shown is None or now - self.shown >= EVERY or done == total:
            self.shown = now
            tail = "; writing the file" if done == total else ""
            print(f"drawn {done}/{total} frames, {now - self.t0:.0f} s{tail}", flush=True)


def main(args: argparse.Namespace) -> int:
    """Handle ``sqpmpc animate``; returns the exit status (2: bad input)."""
    try:
        run = load_run(args.run_dir, args.scenario)
        if args.frame is not None:
            out = args.out or Path(args.run_dir) / f"frame-{args.frame}.png"
            print(f"wrote {write_frame(run, args.frame, out)}")
            return 0
        out = args.out if args.out is not None else Path(args.run_dir) / "animation.gif"
        path, frames = animate(run, out, args.fps, args.step, progress=Progress())
    except (ProblemError, ScenarioError) as exc:
        print(f"sqpmpc animate: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path} ({frames} frames, {args.fps:g} fps)")
    return 0
