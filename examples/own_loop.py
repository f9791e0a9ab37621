"""A centralized controller in your own loop, on a scenario built in code (no TOML).

Two robots swap places head-on. The loop owns the "plant" (here a plain Euler
unicycle; on a robot, the measured poses): it measures, steps the controller,
applies the first input. Halfway, robot 1 is sent to a new goal with
``update_reference``, effective from the next step.

Run ``python examples/own_loop.py`` (``--steps 8`` for a quick look).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

import sqpmpc


def build_scenario() -> sqpmpc.Scenario:
    """Two robots 6 m apart, each going to the other's start (the TOML keys, as Python)."""

    def robot(rid: int, start: tuple[float, float, float], goal: tuple[float, float]):
        return sqpmpc.RobotSpec(id=rid, initial_state=start, diameter=0.3,
                                reference=sqpmpc.PointReference(position=goal))

    return sqpmpc.Scenario(
        name="head-on-in-code", t_end=30.0, sample_time=0.5, horizon=8,
        weights=sqpmpc.Weights(Q=(1.0, 1.0), R=(0.5, 0.5)),
        bounds=sqpmpc.Bounds(v=(-0.6, 0.6), omega=(-math.pi / 4, math.pi / 4)),
        robots=(robot(1, (-3.0, 0.0, 0.0), (3.0, 0.0)),
                robot(2, (3.0, 0.05, math.pi), (-3.0, 0.0))),
    )


def unicycle(states: np.ndarray, inputs: np.ndarray, dt: float) -> np.ndarray:
    """The robots' motion over one sample (Euler step of x' = v cos psi, y' = v sin psi,
    psi' = omega); a real loop measures the poses instead."""
    x, y, psi = states.T
    v, omega = inputs.T
    return np.stack((x + dt * v * np.cos(psi), y + dt * v * np.sin(psi), psi + dt * omega),
                    axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=60, help="samples to run (default 60)")
    args = parser.parse_args()

    scenario = build_scenario()
    controller = sqpmpc.CentralizedController(scenario)
    required = scenario.required_distances()[0, 1]
    new_goal = (3.0, 1.0)
    x = scenario.initial_states()
    min_clearance = math.inf
    fallbacks = 0
    for k in range(args.steps):
        t = k * scenario.sample_time
        if k == args.steps // 2:  # a new goal for robot 1, from this step on
            controller.update_reference(1, sqpmpc.PointReference(position=new_goal))
        out = controller.step(t, x)  # inputs (n, 2) for the states x (n, 3) at time t
        fallbacks += out.fallback is not None
        x = unicycle(x, out.inputs, scenario.sample_time)
        min_clearance = min(min_clearance, float(np.hypot(*(x[0, :2] - x[1, :2]))) - required)
    goal_error = float(np.hypot(*(x[0, :2] - np.array(new_goal))))
    print(f"{args.steps} steps of {scenario.name}: min clearance {min_clearance:.4f} m, "
          f"fallbacks {fallbacks}, robot 1 at ({x[0, 0]:.2f}, {x[0, 1]:.2f}), "
          f"{goal_error:.2f} m from its new goal {new_goal}")


if __name__ == "__main__":
    main()
