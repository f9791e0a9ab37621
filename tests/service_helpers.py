"""Set-ups shared by the services tests: a run's processes over Zenoh on loopback and a
robot controller killed and started again."""

from __future__ import annotations

import os
from pathlib import Path

from services.faults import ENV
from services.messages import decode
from services.testing import Probe, ServiceProcess, free_ports, start_service
from tests import HANG

__all__ = ["assert_lockstep_held", "kill_and_restart", "newest_sample", "start_run"]


def start_run(tmp_path: Path, run: str, ids: list[int], t_end: float, *, scenario: str,
              plant_args: tuple[str, ...] = (), robot_args: tuple[str, ...] = (),
              subscriptions: tuple[tuple[object, ...], ...] = (),
              muted: dict[int, int] | None = None
              ) -> tuple[Probe, ServiceProcess, dict[int, ServiceProcess], str]:
    """A probe (listening first, so the plant connects to it at once), the plant, robots;
    ``muted``: robot -> the sample from which its controller publishes nothing more while
    its token stays (``SQPMPC_FAULTS=mute=K``, :mod:`services.faults`)."""
    ports = free_ports(2 + len(ids))
    probe_ep, plant_ep = (f"tcp/127.0.0.1:{p}" for p in ports[:2])
    probe = Probe(run, [], subscriptions, listen=[probe_ep])
    common = ["--scenario", scenario, "--t-end", str(t_end), "--run", run]
    plant = start_service("plant", [*common, "--listen", plant_ep, "--connect", probe_ep,
                                    "--out", str(tmp_path / "out"), "--no-plots", *plant_args],
                          tmp_path / "logs")
    robots = {
        i: start_service("robot", ["--id", str(i), *common, "--insecure", "--listen",
                                   f"tcp/127.0.0.1:{port}", "--connect", plant_ep, *robot_args],
                         tmp_path / "logs", name=f"robot-{i}",
                         env={**os.environ, ENV: f"mute={muted[i]}"} if i in (muted or {})
                         else None)
        for i, port in zip(ids, ports[2:], strict=True)
    }
    return probe, plant, robots, plant_ep


def newest_sample(probe: Probe) -> int:
    """The newest sample of the plant's states the probe received (-1: none yet)."""
    return max((decode(e.payload, 8).sample for e in probe.events), default=-1)


def kill_and_restart(probe: Probe, plant: ServiceProcess, robots: dict[int, ServiceProcess],
                     procs: list[ServiceProcess], robot: int, sample: int, logs: Path) -> None:
    """``kill -9`` of robot ``robot``'s controller at ``sample``, its command started again
    (without the mute; added to ``procs``), then every process of the lockstep run waited
    for: each must end with status 0.

    The robot must have been started muted from ``sample`` (:func:`start_run`) and the
    plant with ``--timeout HANG``: the lockstep run then stops at ``sample`` until the robot
    has left and rejoined, so the kill lands there however far behind a busy machine makes
    the probe (killed once the probe saw the sample, the run could be over by then)."""
    assert probe.wait_for(lambda: newest_sample(probe) >= sample, HANG), plant.output()
    robots[robot].proc.kill()
    robots[robot].wait(HANG)
    assert probe.wait_for(lambda: f"robot/{robot}" not in probe.alive, HANG)
    assert probe.wait_for(lambda: f"robot/{robot} left at sample" in plant.output(), HANG)
    assert f"robot/{robot} left at sample {sample}:" in plant.output(), plant.output()
    robots[robot] = start_service("robot", robots[robot].argv[3:], logs,
                                  name=f"robot-{robot}-again")
    procs.append(robots[robot])
    assert plant.wait(HANG) == 0, plant.output()
    for r in robots.values():
        assert r.wait(HANG) == 0, r.output()


def assert_lockstep_held(m: dict) -> None:
    """What lockstep guarantees, in a run's ``metrics.json``: the plant applied every robot's
    own input at every sample, none braked.

    In lockstep the plant waits for every input of a sample; it brakes a robot
    (``missed_deadlines``) only when that wait runs out (``--timeout``:
    ``lockstep_timeouts``), or its controller left or sent an inconsistent input. With the
    wait a hang guard (``--timeout HANG``), none of these depends on the machine's load: each
    is a controller stuck, gone, failing or an input lost for good.
    """
    assert m["mode"] == "lockstep", m["mode"]
    assert m["lockstep_timeouts"] == 0, m["lockstep_timeouts"]
    braked = {rid: n for rid, n in m["missed_deadlines_by_robot"].items() if n}
    assert not braked and m["missed_deadlines"] == 0, braked
