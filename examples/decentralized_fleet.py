"""A decentralized fleet stepped by hand: one controller per robot, plans passed between them.

Each robot's controller solves its own QP. After a sample, every controller's
``ControlOutput.plan`` is what that robot would send over the network; here it
is handed to the other controllers with ``update_neighbour_plan`` (as a
message callback would), and the next ``step`` uses the plans it holds. A plan
can be lost (``--drop``): the receiver then predicts that neighbour from its
last two poses (the paper's fallback) and keeps it at the full distance.

Run ``python examples/decentralized_fleet.py`` (``--steps 8`` for a quick look).
"""

from __future__ import annotations

import argparse

import numpy as np

import sqpmpc


def unicycle(states: np.ndarray, inputs: np.ndarray, dt: float) -> np.ndarray:
    """Euler step of the unicycle for every robot (the robots' real motion)."""
    x, y, psi = states.T
    v, omega = inputs.T
    return np.stack((x + dt * v * np.cos(psi), y + dt * v * np.sin(psi), psi + dt * omega),
                    axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="crossing-4", help="built-in name or TOML file")
    parser.add_argument("--steps", type=int, default=None, help="samples (default: to t_end)")
    parser.add_argument("--drop", type=float, default=0.0,
                        help="probability that a plan message is lost (default 0)")
    args = parser.parse_args()

    scenario = sqpmpc.load_scenario(args.scenario)
    steps = scenario.steps if args.steps is None else args.steps
    controllers = {int(rid): sqpmpc.DecentralizedController(scenario, int(rid))
                   for rid in scenario.ids}
    rng = np.random.default_rng(0)
    required = scenario.required_distances()
    pairs = scenario.pairs()
    x, previous = scenario.initial_states(), None
    min_clearance, lost = np.inf, 0
    for k in range(steps):
        t = k * scenario.sample_time
        # every robot computes from the same measured states and the plans it holds
        outs = {rid: c.step(k, t, x, previous_states=previous) for rid, c in controllers.items()}
        # the network: every plan to every other robot, unless lost
        for sender, out in outs.items():
            for receiver, c in controllers.items():
                if receiver == sender:
                    continue
                if rng.random() < args.drop:
                    lost += 1
                    continue
                c.update_neighbour_plan(out.plan)
        u = np.stack([outs[int(rid)].inputs[0] for rid in scenario.ids])
        previous, x = x, unicycle(x, u, scenario.sample_time)
        gaps = np.hypot(*(x[pairs[:, 0], :2] - x[pairs[:, 1], :2]).T)
        min_clearance = min(min_clearance, float(np.min(gaps - required[pairs[:, 0],
                                                                        pairs[:, 1]])))
    goals = scenario.reference_positions(steps * scenario.sample_time)
    errors = np.hypot(*(x[:, :2] - goals).T)
    counters = {rid: c.counters() for rid, c in controllers.items()}
    fallbacks = sum(c["fallbacks"] for c in counters.values())
    estimated = sum(c["fallback_neighbours"] for c in counters.values())
    print(f"{steps} steps of {scenario.name}, {len(controllers)} controllers: "
          f"min clearance {min_clearance:.4f} m, plans lost {lost}, neighbours predicted "
          f"without a plan {estimated}, fallback inputs {fallbacks}, distance to reference "
          + ", ".join(f"{rid}: {e:.2f}" for rid, e in zip(scenario.ids, errors, strict=True))
          + " m")


if __name__ == "__main__":
    main()
