"""Your own loop, recorded: the same run folder as ``sqpmpc run`` from a loop you wrote.

One decentralized controller per robot, a plant that adds the scenario's input
noise (:class:`sqpmpc.Plant`; on real robots, the measured poses), and a
:class:`sqpmpc.RunRecorder` that every sample is appended to. At the end
``RunRecorder.write`` writes ``metrics.json`` (arrivals included),
``trajectory.npz``, ``record.msgpack``, ``recording.mcap`` and the plots; the
folder reads back with ``sqpmpc metrics OUT`` and ``sqpmpc animate OUT``.

Run ``python examples/record_own_loop.py --out runs/mine`` (``--steps 8`` for a
quick look; ``--overwrite`` to replace a previous run in OUT).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import sqpmpc
from sqpmpc.io.recorder import prepare_output
from sqpmpc.io.reporting import summarize


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="crossing-4", help="built-in name or TOML file")
    parser.add_argument("--steps", type=int, default=None, help="samples (default: to t_end)")
    parser.add_argument("--out", type=Path, required=True, help="the run folder to write")
    parser.add_argument("--overwrite", action="store_true", help="replace a run in --out")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    args = parser.parse_args()
    try:  # the output folder is checked before the run, as sqpmpc run does
        prepare_output(args.out, args.overwrite)
        scenario = sqpmpc.load_scenario(args.scenario)
    except sqpmpc.SqpmpcError as exc:
        print(f"record_own_loop.py: error: {exc}", file=sys.stderr)
        return 2

    steps = scenario.steps if args.steps is None else args.steps
    controllers = [sqpmpc.DecentralizedController(scenario, int(rid)) for rid in scenario.ids]
    plant = sqpmpc.Plant(scenario.plant, scenario.sample_time, scenario.n_robots)
    recorder = sqpmpc.RunRecorder(scenario, "decentralized")
    x, previous = scenario.initial_states(), None
    for k in range(steps):
        t = k * scenario.sample_time
        outs = [c.step(k, t, x, previous_states=previous) for c in controllers]
        for c in controllers:  # the network: every plan to every other robot
            for out in outs:
                if out.plan is not None and out.plan.robot_id != c.robot_id:
                    c.update_neighbour_plan(out.plan)
        u = sqpmpc.RunRecorder.inputs_of(outs)
        next_x, applied = plant.step(x, u)
        recorder.append(t, x, outs, plant_inputs=applied)  # states at t, what was applied
        previous, x = x, next_x
    recorder.append(steps * scenario.sample_time, x)  # the final states end the record
    metrics = recorder.write(args.out, plots=not args.no_plots, overwrite=True)
    print(summarize(metrics))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
