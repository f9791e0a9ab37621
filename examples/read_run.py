"""Read a run back: metrics.json and trajectory.npz as ``sqpmpc run`` (or
``sqpmpc.write_run``) writes them, a summary per robot and a clearance plot.

Run ``sqpmpc run paper-s2 --scheme decentralized --out runs/s2`` first, then
``python examples/read_run.py runs/s2`` (writes ``runs/s2/read_run_clearance.png``, beside
the run's own ``clearance.png``, which it leaves alone).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib
import numpy as np

import sqpmpc

matplotlib.use("Agg")  # files only, no window
import matplotlib.pyplot as plt  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="folder holding metrics.json and trajectory.npz")
    parser.add_argument("--plot", type=Path, default=None,
                        help="clearance plot to write (default: RUN/read_run_clearance.png; "
                             "the run's own clearance.png is left alone)")
    args = parser.parse_args()

    metrics = json.loads((args.run / "metrics.json").read_text())
    traj = sqpmpc.load_trajectory(args.run / "trajectory.npz")
    t, states, inputs, ids = traj["t"], traj["states"], traj["inputs"], traj["ids"]
    st = metrics["solve_time"]
    print(f"{metrics['scenario']} / {metrics['scheme']}: {metrics['steps']} steps of "
          f"{metrics['sample_time']} s, horizon {metrics['horizon']}")
    print(f"  min clearance {metrics['min_clearance']:.4f} m, collisions "
          f"{metrics['collisions']}, solver failures {metrics['solver_failures']}, "
          f"controller time median {st['median_ms']:.2f} ms, p99 {st['p99_ms']:.2f} ms")
    steps = np.diff(states[:, :, :2], axis=0)
    path_length = np.hypot(steps[..., 0], steps[..., 1]).sum(axis=0)
    for j, rid in enumerate(ids):
        line = (f"  robot {rid}: path {path_length[j]:.2f} m, RMS tracking error "
                f"{metrics['rms_tracking_error'][str(rid)]:.3f} m, peak |v| "
                f"{np.abs(inputs[:, j, 0]).max(initial=0.0):.2f} m/s")
        if "references" in traj:
            end = np.hypot(*(states[-1, j, :2] - traj["references"][-1, j]))
            line += f", ends {end:.3f} m from its reference"
        print(line)

    # the smallest centre distance over all pairs at every sample
    xy = states[:, :, :2]
    gaps = np.linalg.norm(xy[:, :, None, :] - xy[:, None, :, :], axis=-1)
    n = len(ids)
    gaps[:, np.arange(n), np.arange(n)] = np.inf
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.plot(t, gaps.min(axis=(1, 2)))
    ax.set_xlabel("t [s]")
    ax.set_ylabel("smallest centre distance [m]")
    ax.set_title(f"{metrics['scenario']} / {metrics['scheme']}")
    ax.grid(True, alpha=0.3)
    out = args.plot or args.run / "read_run_clearance.png"
    fig.savefig(out, dpi=100, bbox_inches="tight")
    plt.close(fig)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
