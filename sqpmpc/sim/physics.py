r"""A physics plant: the scenario's robots as rigid bodies in MuJoCo (optional extra).

``pip install 'sqpmpc[physics]'`` installs MuJoCo (one wheel, ``mujoco>=3,<4``);
this module imports it only when a fleet is built and otherwise raises one
:class:`~sqpmpc.errors.DependencyError` naming the extra.

Every robot of the scenario becomes a differential-drive robot
(:class:`PhysicalRobot`): a cylindrical chassis of the robot's diameter and
``mass`` (its inertia from the shape), two wheels on a track of
``track_fraction`` of the diameter, each driven by a velocity servo
(torque :math:`\tau = k_v(\bar w - \dot\theta)` clipped to
``wheel_torque``, the set point :math:`\bar w` a first-order filter of the
command with time constant ``actuator_time_constant``), a frictionless front
caster and a rear anti-tip caster 1 mm above the floor. The wheels grip the
floor with Coulomb friction ``friction``; the physics step is
``physics_step`` (2 ms). Robots and obstacles do not touch physically: their
footprints (the scenario's circles) are checked after every physics step and
the clearances recorded, so an overlap is measured, not hidden by a contact.

The driver is a robot's: at every sample the controller's :math:`(v, \omega)`
become wheel speeds :math:`w_{R,L} = (v \pm \omega b/2)/r`; the true pose
:math:`(x, y, \psi)` of the axle's midpoint and the measured velocities
:math:`(v, \omega)` (the chassis' forward and yaw rates) are read back at the
next sample (:class:`PhysicalSimulation`). For the paper's robot (no
acceleration bounds) the wheel speeds are held over the sample. With
``[bounds] acceleration`` (CONTRACT 1c) a command is the velocity to reach at
the end of the sample at constant acceleration, within the bounds
(:class:`~sqpmpc.problem.plant.Plant`, :mod:`sqpmpc.models.acceleration`), and
the driver gives the servos that ramp (:meth:`PhysicsFleet.ramp`): from the
measured velocities to the command, updated every physics step, led by
``feed_forward`` (the servos' set-point filter delays a ramp by its time
constant; the nominal robot's driver makes up for it).

Why the ramp: the controller checks each first input against the path its
model predicts, within the deviation bound of
:func:`~sqpmpc.problem.plant.acceleration_path_deviation`. Wheel speeds held at
the command (a step) make the nominal robot reach it in about 0.1 s instead of
over the sample: it runs up to :math:`|\Delta v| T_s/2` ahead of the
prediction when speeding up and behind it when braking (0.12 m measured on
corridor), outside the checked tube in half the samples, and the checks then
fell back to braking (corridor decentralized: 11 brake fallbacks, cost 1.20x the
ideal plant). A physical robot also moves on arcs: declare ``[plant] model =
"exact"`` (``benchmarks/physical.py`` does), else the Euler plant's straight
segment misses up to :math:`v\omega T_s^2/2` (0.059 m at the paper's bounds).
With both the nominal robot stays within 1.2 mm of the tube
(``tube_excursion`` of :meth:`PhysicalSimulation.physics_metrics`).

What the controllers are told (:func:`physical_plant`): the robots move on arcs
(``[plant] model = "exact"``, whatever the scenario declares), and the paper's robot's
speed lags its commands (``[plant] response`` of :meth:`PhysicalRobot.response`,
:mod:`sqpmpc.problem.plant`, "A plant that lags"). Without them the paper's robots
head-on overlapped up to 122 mm: the checks took the Euler segments (each robot ended a
sample 4 cm off its segment) and a stop at once (a robot coasts 45 mm from 0.6 m/s).
With them the paper's robots stay within 0.3 mm of the checked tubes and keep their
distance at every physics step (``tests/test_physics.py``, with every QP solver).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import DependencyError, ProblemError
from sqpmpc.problem.obstacles import obstacle_positions
from sqpmpc.problem.plant import ramp_accelerations
from sqpmpc.problem.scenario import Scenario
from sqpmpc.sim.record import RunRecord
from sqpmpc.sim.simulation import ClosedLoopSimulation, Scheme, SimulationOptions
from sqpmpc.sim.tube import tube_excursion

__all__ = ["CASTER_MASS", "OVERLAP_TOLERANCE", "PhysicalRobot", "PhysicalSimulation",
           "PhysicsFleet", "fleet_xml", "load_mujoco", "physical_plant", "simulate_physical"]

#: Clearance below which a physics step counts as an overlap, m (the QP's 1 mm margin).
OVERLAP_TOLERANCE = 1e-3
#: Mass of each of a robot's two caster spheres, kg.
CASTER_MASS = 0.01


def load_mujoco() -> Any:
    """The ``mujoco`` module, or a :class:`DependencyError` naming the extra."""
    try:
        import mujoco
    except ImportError as exc:
        raise DependencyError("the physics plant needs MuJoCo: install the 'physics' extra "
                              "(pip install 'sqpmpc[physics]', i.e. mujoco>=3,<4)") from exc
    return mujoco


def _positive(name: str, value: object, unit: str) -> float:
    if (isinstance(value, bool) or not isinstance(value, int | float | np.floating)
            or not math.isfinite(value) or value <= 0):
        raise ProblemError(f"PhysicalRobot.{name}: expected a finite number > 0 ({unit}), "
                           f"got {value!r}")
    return float(value)


@dataclass(frozen=True)
class PhysicalRobot:
    """The physical robot every robot of a scenario becomes.

    Parameters
    ----------
    mass
        Chassis mass, kg (each wheel adds ``wheel_mass``).
    wheel_torque
        Largest torque of each wheel's motor, N m.
    friction
        Coulomb friction coefficient of the wheels on the floor.
    actuator_time_constant
        Time constant of the first-order filter on each wheel's speed set point, s.
    wheel_radius
        m.
    track_fraction
        Distance between the wheels as a fraction of the robot's diameter.
    servo_gain
        :math:`k_v` of the wheel velocity servos, N m s/rad.
    wheel_mass
        kg, each.
    wheel_armature
        Reflected rotor inertia of each wheel's motor and gear, kg m^2.
    physics_step
        MuJoCo's time step, s (the sample time must be a multiple of it).
    feed_forward
        How far ahead the driver's set-point ramp runs, s (>= 0; robots with
        acceleration bounds): the nominal set-point filter's time constant, which
        delays a ramp by as much. A driver is tuned once: sweeping
        ``actuator_time_constant`` leaves it at the nominal 0.02 s.
    """

    mass: float = 3.0
    wheel_torque: float = 0.5
    friction: float = 1.0
    actuator_time_constant: float = 0.02
    wheel_radius: float = 0.05
    track_fraction: float = 0.8
    servo_gain: float = 1.0
    wheel_mass: float = 0.1
    wheel_armature: float = 0.002
    physics_step: float = 0.002
    feed_forward: float = 0.02

    def __post_init__(self) -> None:
        for name, unit in (("mass", "kg"), ("wheel_torque", "N m"), ("friction", "-"),
                           ("actuator_time_constant", "s"), ("wheel_radius", "m"),
                           ("track_fraction", "-"), ("servo_gain", "N m s/rad"),
                           ("wheel_mass", "kg"), ("wheel_armature", "kg m^2"),
                           ("physics_step", "s")):
            object.__setattr__(self, name, _positive(name, getattr(self, name), unit))
        lead = self.feed_forward
        if (isinstance(lead, bool) or not isinstance(lead, int | float | np.floating)
                or not math.isfinite(lead) or lead < 0):
            raise ProblemError(f"PhysicalRobot.feed_forward: expected a finite number >= 0 "
                               f"(s), got {lead!r}")
        object.__setattr__(self, "feed_forward", float(lead))
        if self.track_fraction >= 1.0:
            raise ProblemError(f"PhysicalRobot.track_fraction: expected a number in (0, 1) (the "
                               f"wheels inside the footprint), got {self.track_fraction!r}")

    def response(self) -> tuple[float, float]:
        r"""How the paper's robot's speed follows a command on this robot (the driver holds
        the wheel speeds): ``(delay, acceleration)`` of :attr:`PlantSpec.response
        <sqpmpc.problem.plant.PlantSpec>`, from the parameters.

        Each wheel's speed follows its set point through two first-order lags, the set-point
        filter (``actuator_time_constant``) and the servo, :math:`J/k_v` with
        :math:`J = m_e r^2/2` the robot's effective mass :math:`m_e` (chassis, wheels,
        casters and the wheels' and motors' rotating inertia reflected to the floor,
        :math:`2(J_w + J_a)/r^2`) shared by the two wheels; the lag of two first-order lags
        in series is the sum of their time constants: ``delay``. While the torque is at its
        limit the robot's speed changes at :math:`2\tau_{\max}/(r m_e)`: ``acceleration``
        (4.07 m/s^2 for the nominal robot, as measured by ``benchmarks/physical.py``), which
        takes the wheels gripping (friction 1 holds 9.8 m/s^2). ``tests/test_physics.py``
        checks the resulting bound against the robot's paths after steps between the
        corners of the paper's input box.
        """
        r = self.wheel_radius
        rotating = 2.0 * (self.wheel_armature + 0.5 * self.wheel_mass * r * r) / (r * r)
        mass = self.mass + 2.0 * self.wheel_mass + 2.0 * CASTER_MASS + rotating
        servo = 0.5 * mass * r * r / self.servo_gain
        return (self.actuator_time_constant + servo, 2.0 * self.wheel_torque / (r * mass))

    def substeps(self, sample_time: float) -> int:
        """Physics steps per controller sample (``sample_time`` must be a multiple)."""
        n = round(sample_time / self.physics_step)
        if n < 1 or abs(n * self.physics_step - sample_time) > 1e-9 * max(sample_time, 1.0):
            raise ProblemError(f"the sample time {sample_time} s is not a multiple of the "
                               f"physics step {self.physics_step} s")
        return n


def fleet_xml(scenario: Scenario, robot: PhysicalRobot) -> str:
    """The MJCF model of the scenario's robots at their initial poses (see module notes)."""
    r, tau, kv = robot.wheel_radius, robot.actuator_time_constant, robot.servo_gain
    mu = robot.friction
    parts = [
        '<mujoco model="sqpmpc-fleet">',
        f'<option timestep="{robot.physics_step!r}" integrator="implicitfast"/>',
        '<default><geom contype="2" conaffinity="1" solref="0.005 1"/></default>',
        '<worldbody>',
        '<geom name="floor" type="plane" size="0 0 1" contype="1" conaffinity="2" solref="0.005 1" '
        f'friction="{mu!r} 0.0001 0.00001"/>',
    ]
    actuators = []
    for spec in scenario.robots:
        x, y, psi = spec.initial_state
        radius = 0.5 * spec.diameter
        half_track = 0.5 * robot.track_fraction * spec.diameter
        caster = max(0.4 * r, 0.01)
        reach = min(radius - caster, 0.8 * radius)
        name = f"r{spec.id}"
        quat = f"{math.cos(psi / 2)!r} 0 0 {math.sin(psi / 2)!r}"
        parts += [
            f'<body name="{name}" pos="{x!r} {y!r} {r!r}" quat="{quat}">',
            '<freejoint/>',
            # the chassis: no contact (footprints are checked, not collided)
            f'<geom name="{name}_chassis" type="cylinder" size="{radius!r} 0.03" '
            f'pos="0.02 0 0.01" mass="{robot.mass!r}" contype="0" conaffinity="0"/>',
            f'<geom name="{name}_caster" type="sphere" size="{caster!r}" '
            f'pos="{reach!r} 0 {caster - r!r}" mass="{CASTER_MASS!r}" condim="1" priority="1"/>',
            f'<geom name="{name}_skid" type="sphere" size="{caster!r}" '
            f'pos="{-reach!r} 0 {caster - r + 0.001!r}" mass="{CASTER_MASS!r}" condim="1" '
            'priority="1"/>',
        ]
        for side, sign in (("left", 1.0), ("right", -1.0)):
            parts += [
                f'<body name="{name}_{side}" pos="0 {sign * half_track!r} 0">',
                f'<joint name="{name}_{side}" type="hinge" axis="0 1 0" '
                f'armature="{robot.wheel_armature!r}"/>',
                f'<geom type="cylinder" size="{r!r} 0.003" zaxis="0 1 0" '
                f'mass="{robot.wheel_mass!r}" condim="3" friction="{mu!r} 0.0001 0.00001"/>',
                '</body>',
            ]
            actuators.append(
                f'<general joint="{name}_{side}" dyntype="filter" dynprm="{tau!r}" '
                f'gaintype="fixed" gainprm="{kv!r}" biastype="affine" biasprm="0 0 {-kv!r}" '
                f'forcelimited="true" forcerange="{-robot.wheel_torque!r} '
                f'{robot.wheel_torque!r}"/>')
        parts.append('</body>')
    parts += ['</worldbody>', '<actuator>', *actuators, '</actuator>', '</mujoco>']
    return "\n".join(parts)


class PhysicsFleet:
    """The scenario's robots in MuJoCo, stepped one controller sample at a time.

    Parameters
    ----------
    scenario
        The robots (diameters, initial states), obstacles and sample time.
    robot
        The physical robot (default :class:`PhysicalRobot`).

    Attributes
    ----------
    pair_clearance, obstacle_clearance
        Per physics step so far: the smallest footprint clearance between two
        robots, and between a robot and an obstacle, m (``inf`` when there is
        none); lists of floats.
    path
        Per physics step so far: the robots' positions ``(n, 2)``.
    """

    def __init__(self, scenario: Scenario, robot: PhysicalRobot | None = None) -> None:
        mj = load_mujoco()
        self._mj = mj
        self.robot = robot or PhysicalRobot()
        self.scenario = scenario
        self.spec = scenario.plant
        self.substeps = self.robot.substeps(scenario.sample_time)
        self.model = mj.MjModel.from_xml_string(fleet_xml(scenario, self.robot))
        self.data = mj.MjData(self.model)
        n = scenario.n_robots
        body = [mj.mj_name2id(self.model, mj.mjtObj.mjOBJ_BODY, f"r{s.id}")
                for s in scenario.robots]
        self._qpos = np.array([self.model.jnt_qposadr[self.model.body_jntadr[b]] for b in body])
        self._qvel = np.array([self.model.jnt_dofadr[self.model.body_jntadr[b]] for b in body])
        d = scenario.diameters()
        self._half_track = 0.5 * self.robot.track_fraction * d
        iu = np.triu_indices(n, 1)
        self._pairs = iu
        self._required = 0.5 * (d[:, None] + d[None, :])[iu]
        self._obstacles = scenario.obstacles
        self._obstacle_required = 0.5 * (d[:, None] + np.array(
            [o.diameter for o in scenario.obstacles]).reshape(1, -1))
        self.pair_clearance: list[float] = []
        self.obstacle_clearance: list[float] = []
        #: ``(n, 2)`` the robots' positions after every physics step so far
        self.path: list[np.ndarray] = []
        mj.mj_forward(self.model, self.data)
        self._settle()

    def _settle(self) -> None:
        """Let the robots come to rest on the floor (0.2 s, wheels held; time reset)."""
        mj = self._mj
        start = self.data.qpos.copy()
        for _ in range(int(0.2 / self.robot.physics_step)):
            mj.mj_step(self.model, self.data)
        # keep the settled height and tilt, put x, y, yaw back exactly
        q = self.data.qpos
        for i, a in enumerate(self._qpos):
            q[a:a + 2] = start[a:a + 2]
            psi = self.scenario.robots[i].initial_state[2]
            q[a + 3:a + 7] = (math.cos(psi / 2), 0.0, 0.0, math.sin(psi / 2))
        self.data.qvel[:] = 0.0
        self.data.act[:] = 0.0
        self.data.time = 0.0
        mj.mj_forward(self.model, self.data)

    def poses(self) -> np.ndarray:
        """True poses ``(n, 3)``: the axle midpoints and the headings."""
        q = self.data.qpos
        out = np.empty((self._qpos.size, 3))
        for i, a in enumerate(self._qpos):
            w, x, y, z = q[a + 3:a + 7]
            out[i] = q[a], q[a + 1], math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        return out

    def velocities(self) -> np.ndarray:
        """Measured ``(v, omega)`` ``(n, 2)``: forward speed and yaw rate of each chassis."""
        qv = self.data.qvel
        psi = self.poses()[:, 2]
        out = np.empty((self._qvel.size, 2))
        for i, a in enumerate(self._qvel):
            # free joint: linear velocity in the world frame, angular in the body frame
            xmat = self.data.xmat[self.model.dof_bodyid[a]].reshape(3, 3)
            out[i, 0] = qv[a] * math.cos(psi[i]) + qv[a + 1] * math.sin(psi[i])
            out[i, 1] = float(xmat[2] @ qv[a + 3:a + 6])
        return out

    @property
    def has_velocities(self) -> bool:
        """Whether the controllers take the measured velocities: the scenario declares
        acceleration bounds (CONTRACT 1c), so its robots have velocity states."""
        return bool(getattr(self.scenario.bounds, "dynamic_limits", False))

    def measure(self, states: np.ndarray) -> np.ndarray:
        """What the robots' odometry gives the controllers: the poses ``states (n, 3)``,
        with the measured velocities appended ``(n, 5)`` when :attr:`has_velocities`."""
        if not self.has_velocities:
            return states
        return np.concatenate((states, self.velocities()), axis=1)

    def wheel_speeds(self, inputs: np.ndarray) -> np.ndarray:
        """The driver's wheel speed commands ``(n, 2)`` (left, right), rad/s, of ``(v, omega)``."""
        v, w = inputs[:, 0], inputs[:, 1]
        r = self.robot.wheel_radius
        return np.stack(((v - w * self._half_track) / r, (v + w * self._half_track) / r), axis=1)

    def _clearances(self) -> None:
        p = self.data.qpos[self._qpos[:, None] + np.arange(2)]
        self.path.append(p)
        if self._required.size:
            i, j = self._pairs
            gap = np.hypot(p[i, 0] - p[j, 0], p[i, 1] - p[j, 1]) - self._required
            self.pair_clearance.append(float(gap.min()))
        else:
            self.pair_clearance.append(math.inf)
        if self._obstacles:
            o = obstacle_positions(self._obstacles, self.data.time)
            gap = np.hypot(p[:, None, 0] - o[None, :, 0], p[:, None, 1] - o[None, :, 1])
            self.obstacle_clearance.append(float((gap - self._obstacle_required).min()))
        else:
            self.obstacle_clearance.append(math.inf)

    def step(self, states: np.ndarray, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hold ``inputs (n, 2)`` for one sample; the true poses after it and the commands.

        ``states`` (what the controllers measured) is not used: the bodies hold the
        true state. The footprint clearances are recorded after every physics step.
        """
        u = np.asarray(inputs, dtype=float)
        if not self.has_velocities:  # the paper's robot: its velocities change at once
            self.data.ctrl[:] = self.wheel_speeds(u).ravel()
            for _ in range(self.substeps):
                self._mj.mj_step(self.model, self.data)
                self._clearances()
            return self.poses(), u.copy()
        start, accel = self.ramp(u)
        dt, lead = self.robot.physics_step, self.robot.feed_forward
        for j in range(1, self.substeps + 1):
            self.data.ctrl[:] = self.wheel_speeds(start + (j * dt + lead) * accel).ravel()
            self._mj.mj_step(self.model, self.data)
            self._clearances()
        return self.poses(), u.copy()

    def ramp(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""The driver's set-point ramp of a sample (robots with acceleration bounds): from
        the measured velocities :math:`(v_0, \omega_0)` at constant accelerations
        :math:`\mathrm{clip}((u - v_0)/T_s, a_{\min}, a_{\max})` (the declared bounds), so
        the set point reaches the command ``inputs (n, 2)`` at the end of the sample when
        the bounds allow: what a command means to the controller's model
        (:class:`~sqpmpc.problem.plant.Plant`, CONTRACT 1c); :meth:`step` sets the
        servos to the ramp ``feed_forward`` seconds ahead. Returns the start ``(n, 2)``
        and the accelerations ``(n, 2)``."""
        b = self.scenario.bounds
        start = self.velocities()
        accel = ramp_accelerations(inputs, start, self.scenario.sample_time,
                                   b.acceleration_lower(), b.acceleration_upper())
        return start, accel


class PhysicalSimulation(ClosedLoopSimulation):
    """:class:`~sqpmpc.sim.simulation.ClosedLoopSimulation` on a :class:`PhysicsFleet`.

    The controllers, plan exchange and record are the in-process loop's; only the
    plant differs. The controllers take the ``[plant]`` of :func:`physical_plant` (the
    robots move on arcs; the paper's robot lags), which :attr:`scenario` holds
    (module notes; :meth:`tube_excursion` measures what the checks missed).

    Parameters
    ----------
    scenario, scheme, settings, options
        As for :class:`~sqpmpc.sim.simulation.ClosedLoopSimulation`.
    robot
        The physical robot (default :class:`PhysicalRobot`).

    Attributes
    ----------
    velocities
        ``(K+1, n, 2)`` measured :math:`(v, \\omega)` at every sample.
    fleet
        The :class:`PhysicsFleet` (its per-physics-step clearances).
    """

    def __init__(self, scenario: Scenario, scheme: Scheme,
                 settings: SolverSettings | None = None,
                 options: SimulationOptions | None = None,
                 robot: PhysicalRobot | None = None) -> None:
        robot = robot or PhysicalRobot()
        super().__init__(physical_plant(scenario, robot), scheme, settings, options)
        self.fleet = PhysicsFleet(self.scenario, robot)
        self.plant = self.fleet
        self.states[0] = self.fleet.poses()
        self.velocities = np.zeros((self.scenario.steps + 1, self.scenario.n_robots, 2))

    def step(self) -> None:
        """Advance one sample; then read the measured velocities."""
        super().step()
        self.velocities[self.k] = self.fleet.velocities()

    def physics_metrics(self) -> dict[str, Any]:
        """Clearances at every physics step so far: the smallest robot-robot and
        robot-obstacle clearances (m, ``None`` when there is no pair / obstacle), the
        physics steps below :data:`OVERLAP_TOLERANCE` (``overlap_steps``,
        ``obstacle_overlap_steps``) and :meth:`tube_excursion`."""
        out: dict[str, Any] = {"physics_steps": len(self.fleet.pair_clearance),
                               "tube_excursion": self.tube_excursion()}
        for key, values in (("", self.fleet.pair_clearance),
                            ("obstacle_", self.fleet.obstacle_clearance)):
            arr = np.asarray(values)
            finite = arr[np.isfinite(arr)]
            out[f"physics_min_{key}clearance"] = float(finite.min()) if finite.size else None
            out[f"{key}overlap_steps"] = int(np.count_nonzero(finite < -OVERLAP_TOLERANCE))
        return out

    def tube_excursion(self) -> float:
        """How far the robots' true paths left the tubes the controllers checked, m
        (:func:`~sqpmpc.sim.tube.tube_excursion` of the samples so far)."""
        if self.k == 0:
            return 0.0
        k, steps = self.k, self.fleet.substeps
        path = np.asarray(self.fleet.path[:k * steps]).reshape(k, steps, -1, 2)
        return tube_excursion(path, self.states[:k + 1], self.horizons[:k], self.inputs[:k],
                              self.velocities[:k] if self.fleet.has_velocities else None,
                              self.scenario.sample_time, self.settings.discretization,
                              self.scenario.plant)

    def record(self) -> RunRecord:
        """The loop's record with :meth:`physics_metrics` in ``extra``."""
        rec = super().record()
        rec.extra.update(self.physics_metrics())
        rec.extra["plant_discretization"] = "mujoco"
        return rec


def physical_plant(scenario: Scenario, robot: PhysicalRobot) -> Scenario:
    r"""The scenario with the ``[plant]`` the physics plant's robots are: what the
    controllers' margins and checks take (:mod:`sqpmpc.problem.plant`).

    - ``model = "exact"`` whatever was declared: a physical robot moves continuously, on
      arcs when it turns. Under the Euler (or RK4) plant the controllers take the robots
      to move on the predicted straight segments and keep no margin for the arcs: the
      paper's robots head-on ended a sample 71 mm inside each other's distance, each
      4 cm off its Euler segment, where the check had accepted 3.5 mm of clearance.
    - for the paper's robot (no acceleration bounds) ``response =``
      :meth:`PhysicalRobot.response`: its speed cannot change at once, it coasts (45 mm
      from 0.6 m/s) and lags a change of command; the checks take both, so the brake that
      follows an accepted input (which the paper's robot takes to stop at once) is safe.
      Head-on, a robot braking from full speed coasted 22 mm into the other's distance
      after the check had accepted the 33 mm left. Robots with acceleration bounds ramp
      as their model predicts (:meth:`PhysicsFleet.ramp`) and keep their own bound.
    """
    response = None if scenario.bounds.dynamic_limits else robot.response()
    plant = dataclasses.replace(scenario.plant, model="exact", response=response)
    return scenario if plant == scenario.plant else scenario.with_changes(plant=plant)


def simulate_physical(scenario: Scenario, scheme: Scheme,
                      settings: SolverSettings | None = None,
                      options: SimulationOptions | None = None,
                      robot: PhysicalRobot | None = None) -> RunRecord:
    """Run a whole closed loop on the physics plant; see :class:`PhysicalSimulation`."""
    return PhysicalSimulation(scenario, scheme, settings, options, robot).run()
