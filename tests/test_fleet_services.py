"""Distributed fleets: plan filtering and several robots per process, over real Zenoh.

The services run as real processes with real Zenoh sessions on 127.0.0.1
(multicast scouting off); nothing is mocked. The filtering rule itself is
checked without Zenoh against the controller's own neighbour selection.
"""

from __future__ import annotations

import functools
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from services.messages import InvalidMessage, PlanMsg, encode, peek_plan
from services.plans import PlanStore, StepPlans, recipients
from services.protocol import AcceptancePolicy
from services.testing import child_pids, pid_alive
from services.validator import MessageValidator
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.kernels.collision import nearest_within
from sqpmpc.problem.fleets import antipodal_swap
from sqpmpc.sim.simulation import simulate
from tests import HANG
from tests.service_helpers import assert_lockstep_held

# a guard against a hang only (no budget on how long a right run takes on a busy machine)
pytestmark = pytest.mark.timeout(900)

ROOT = Path(__file__).resolve().parent.parent


def _launch(*args: str) -> subprocess.CompletedProcess:
    """The launcher to its end (no wall budget: the module's timeout guards a hang); the
    plant's lockstep wait for a sample's inputs is a hang guard too (``--timeout HANG``)."""
    cmd = [sys.executable, "-m", "services.launch", "--no-plots", "--scheme", "decentralized",
           "--timeout", str(HANG), *args]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)


def _plan_counts(stderr: str) -> dict[int, tuple[int, int, int]]:
    """Per robot: plans received, decoded, sent addressed (from the robots' last log line)."""
    found = re.findall(r"robot (\d+): (\d+) plans received, (\d+) decoded, (\d+) sent addressed",
                       stderr)
    return {int(r): (int(a), int(b), int(c)) for r, a, b, c in found}


def _in_order(stderr: str) -> dict[int, dict[int, tuple[int, int]]]:
    """Per receiving robot, per sender: plans received in order and the newest one's sample
    (:attr:`services.plans.PlanStore.in_order`, from the robots' last log line)."""
    found = re.findall(r"robot (\d+): plans in order per sender \(sender:count@newest "
                       r"sample\): ([\d:@ ]*)", stderr)
    return {int(r): {int(j): (int(n), int(s))
                     for j, n, s in re.findall(r"(\d+):(\d+)@(\d+)", text)}
            for r, text in found}


def _addressed(scenario, states: np.ndarray, settings: SolverSettings
               ) -> dict[tuple[int, int], list[int]]:
    """Per (sender, receiver): the samples whose plan the sender addressed to the receiver,
    from the run's states (each sender's own rule: its selector's ``recipients``)."""
    ids = [int(i) for i in scenario.ids]
    out: dict[tuple[int, int], list[int]] = {}
    for rid in ids:
        selector = DecentralizedController(scenario, rid, settings).selector
        for k in range(scenario.steps):
            for j in selector.recipients(states[k]):
                out.setdefault((rid, ids[int(j)]), []).append(k)
    return out


@functools.cache
def _swap_12_in_process():
    """The in-process run both hosted fleets (peers, router) must equal: computed once."""
    scenario = antipodal_swap(12).with_changes(t_end=12.0)
    return scenario, simulate(scenario, "decentralized", SolverSettings(neighbour_slots=3))


@pytest.mark.parametrize("router", [False, True], ids=["peers", "router"])
def test_hosted_filtered_fleet_equals_the_in_process_run(tmp_path, router):
    """12 robots, 3 per process, 3 slots: each robot decodes only the plans it reads."""
    scenario, reference = _swap_12_in_process()
    path = tmp_path / "swap-12.toml"
    path.write_text(scenario.to_toml())
    out = tmp_path / "run"
    res = _launch("--scenario", str(path), "--out", str(out), "--neighbour-slots", "3",
                  "--robots-per-process", "3", "--log-level", "INFO",
                  *(["--router"] if router else []))
    assert res.returncode == 0, res.stderr[-3000:]
    traj = np.load(out / "trajectory.npz")
    assert np.array_equal(traj["states"], reference.states)
    assert np.array_equal(traj["inputs"], reference.inputs)
    m = json.loads((out / "metrics.json").read_text())
    assert m["counters"] == reference.extra["counters"]
    assert_lockstep_held(m)  # no robot braked: its own input applied at every sample
    assert m["collisions"] == 0 and m["invalid_messages"] == 0
    assert m["counters"]["fallback_neighbours"] == reference.extra["counters"][
        "fallback_neighbours"]
    counts = _plan_counts(res.stderr)
    assert sorted(counts) == list(range(1, 13))
    received = sum(c[0] for c in counts.values())
    # the whole fleet's traffic would be 11 plans per robot and sample; far ones were not sent
    assert 0 < received < 0.8 * 12 * 11 * scenario.steps
    assert all(c[1] <= c[0] for c in counts.values())
    # no plan lost on the way: a sender's plans to one receiver go over one reliable,
    # ordered link, so each receiver got, from each sender, every plan it was sent up to
    # the newest it got. Only plans sent after that may be missing: still on their way when
    # the run ended (under load, those of the last samples; how many depends on the load)
    addressed = _addressed(scenario, traj["states"], SolverSettings(neighbour_slots=3))
    assert {j: sum(len(v) for (s, _), v in addressed.items() if s == j)
            for j in range(1, 13)} == {j: c[2] for j, c in counts.items()}  # the robots' rule
    in_order = _in_order(res.stderr)
    assert sorted(in_order) == list(range(1, 13))
    for receiver, senders in in_order.items():
        assert all((j, receiver) in addressed for j in senders), (receiver, senders)
    gaps = {}
    for (sender, receiver), samples in addressed.items():
        count, newest = in_order[receiver].get(sender, (0, -1))
        if count != sum(1 for k in samples if k <= newest) or (count and newest not in samples):
            gaps[sender, receiver] = (count, newest, samples)
    assert not gaps, gaps


def test_without_filtering_every_plan_is_received(tmp_path):
    scenario = antipodal_swap(6).with_changes(t_end=3.0)
    path = tmp_path / "swap-6.toml"
    path.write_text(scenario.to_toml())
    out = tmp_path / "run"
    res = _launch("--scenario", str(path), "--out", str(out), "--neighbour-slots", "2",
                  "--all-plans", "--robots-per-process", "6", "--log-level", "INFO")
    assert res.returncode == 0, res.stderr[-3000:]
    reference = simulate(scenario, "decentralized", SolverSettings(neighbour_slots=2))
    assert np.array_equal(np.load(out / "trajectory.npz")["states"], reference.states)
    counts = _plan_counts(res.stderr)
    assert sorted(counts) == list(range(1, 7))
    assert all(c[0] == c[1] and c[2] == 0 for c in counts.values()), counts
    # each robot got from each of the 5 others the plan of every sample up to the newest it
    # got (one ordered link: none lost on the way), and at its last step it waited for
    # theirs of the sample before; the last sample's may still be on their way at the end
    in_order = _in_order(res.stderr)
    assert sorted(in_order) == list(range(1, 7))
    assert all(sorted(senders) == [j for j in range(1, 7) if j != r]
               and all(n == newest + 1 and newest >= scenario.steps - 2
                       for n, newest in senders.values())
               for r, senders in in_order.items()), in_order


def test_sigterm_stops_hosted_robots_and_the_plant_writes(tmp_path):
    out = tmp_path / "term"
    cmd = [sys.executable, "-m", "services.launch", "--scenario", "paper-s2", "--scheme",
           "decentralized", "--mode", "realtime", "--out", str(out), "--no-plots",
           "--robots-per-process", "2"]
    launcher = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                cwd=ROOT)
    try:
        children: list[int] = []
        while launcher.poll() is None and len(children) < 3:  # however long they take
            children = child_pids(launcher.pid)
            time.sleep(0.1)
        assert len(children) == 3, "plant and 2 processes of 2 robots should be running"
        # the run going (the plant's record growing), not a fixed 3 s that on a loaded
        # machine ends while the processes still import and leaves the plant less than its
        # grace to write: however long the start takes
        record = out / "record.msgpack"
        while launcher.poll() is None and not (record.exists() and record.stat().st_size > 0):
            time.sleep(0.1)
        time.sleep(1.0)  # two more samples of the real-time run (Ts = 0.5 s)
        launcher.send_signal(signal.SIGTERM)
        _, err = launcher.communicate()
    finally:
        if launcher.poll() is None:
            launcher.kill()
            launcher.wait()
    assert launcher.returncode == 128 + signal.SIGTERM, err
    assert "killing" not in err
    assert not [pid for pid in children if pid_alive(pid)]
    m = json.loads((out / "metrics.json").read_text())
    assert m["completed"] is False and m["interrupted"] == "SIGINT"


def test_bad_robots_per_process_is_refused():
    res = subprocess.run([sys.executable, "-m", "services.launch", "--scenario", "paper-s2",
                          "--scheme", "decentralized", "--robots-per-process", "0"],
                         capture_output=True, text=True, timeout=HANG, cwd=ROOT)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("services.launch: error: "), res.stderr


# ------------------------------------------------------------- the rule, without Zenoh
def _selected(states: np.ndarray, i: int, radius: np.ndarray, slots: int) -> set[int]:
    n = states.shape[0]
    others = np.array([j for j in range(n) if j != i], dtype=np.int64)
    chosen = np.zeros(slots, dtype=np.int64)
    rest = np.zeros(n - 1, dtype=np.int64)
    p = np.ascontiguousarray(states[:, :2])
    used, _ = nearest_within(p[i], p, others, np.ascontiguousarray(radius[i, others]),
                             chosen, rest)
    return {int(others[e]) for e in chosen[:used]}


@pytest.mark.parametrize("seed", range(6))
def test_a_plan_reaches_every_robot_that_gives_its_sender_a_slot(seed):
    """For any motion within v_max Ts per robot, a robot that selects j at k + 1 is
    among j's recipients at k (the rule a lockstep run relies on)."""
    rng = np.random.default_rng(seed)
    n, slots, v_max, ts, horizon = 24, 4, 0.6, 0.1, 8
    # dense: a cluster where the slot limit decides, plus robots at the edge of reach
    states = np.zeros((n, 3))
    states[:, :2] = rng.normal(scale=1.0 + seed * 0.4, size=(n, 2))
    d = np.full((n, n), 0.3)
    np.fill_diagonal(d, 0.0)
    radius = d + 0.001 + 2 * v_max * horizon * ts
    step = 2 * v_max * ts
    sent = {j: set(recipients(states, j, radius, slots, step).tolist()) for j in range(n)}
    total = sum(len(s) for s in sent.values())
    assert total < n * (n - 1)  # something was filtered
    for _ in range(40):
        angle = rng.uniform(0, 2 * np.pi, n)
        speed = v_max * ts * rng.choice([0.0, 1.0, rng.uniform()], size=n)
        nxt = states.copy()
        nxt[:, 0] += speed * np.cos(angle)
        nxt[:, 1] += speed * np.sin(angle)
        for i in range(n):
            for j in _selected(nxt, i, radius, slots):
                assert i in sent[j], (i, j)


def test_peek_reads_the_header_and_the_store_decodes_when_read():
    horizon = 8
    validator = MessageValidator([1, 2, 3], horizon)
    plan = PlanMsg(2, 300, 1.0, 0.0, np.ones((horizon + 1, 3)), np.zeros((horizon, 2)))
    payload = encode(plan)
    assert peek_plan(payload) == (2, 300)
    assert peek_plan(b"\x00garbage") is None and peek_plan(payload[:14]) is None
    store = PlanStore(validator, [2, 3], AcceptancePolicy(1000, 0.5, horizon), lambda: 300)
    store.add(2, payload)
    assert store.has(2, 300) and not store.has(2, 301) and store.decoded == 0
    broken = payload[:-8]  # a good header over a short body: refused when read
    store.add(3, encode(PlanMsg(3, 299, 1.0, 0.0, np.ones((horizon + 1, 3)),
                                np.zeros((horizon, 2)))))
    store.add(3, broken.replace(b"\xa2id\x02", b"\xa2id\x03", 1))
    store.add(3, encode(PlanMsg(3, 10, 1.0, 0.0, np.ones((horizon + 1, 3)),
                                np.zeros((horizon, 2)))))  # too old at 300: dropped as stale
    assert validator.stale == 1 and validator.invalid == 0
    with pytest.raises(InvalidMessage):  # far ahead of the robot's cursor: refused
        store.add(3, encode(PlanMsg(3, 2**62, 1.0, 0.0, np.ones((horizon + 1, 3)),
                                    np.zeros((horizon, 2)))))
    assert validator.invalid == 1
    plans = StepPlans(store, 301, [2, 3])
    assert plans[2].sample == 300 and np.array_equal(plans[2].states, plan.states)
    assert plans[3].sample == 299  # the newest valid one: sample 300 was broken
    assert validator.invalid == 2 and store.decoded == 2
    assert set(plans) == {2, 3} and len(plans) == 2
    assert StepPlans(store, 301, [2]).get(3) is None  # not a candidate


def test_the_store_counts_the_plans_of_each_sender_that_came_in_order():
    """``in_order``: what the hosted fleet's test checks for a plan lost on the way."""
    horizon = 8
    cursor = [10]
    store = PlanStore(MessageValidator([1, 2, 3], horizon), [2, 3],
                      AcceptancePolicy(1000, 0.5, horizon), lambda: cursor[0])

    def plan(rid: int, sample: int) -> bytes:
        return encode(PlanMsg(rid, sample, 0.5 * sample, 0.0, np.ones((horizon + 1, 3)),
                              np.zeros((horizon, 2))))

    for k in (4, 5, 7):  # 6 lost on the way: 7 came after it
        store.add(2, plan(2, k))
    store.add(2, plan(2, 5))  # a copy sent again: a repeat, not counted
    store.add(3, plan(3, 0))  # too old by now (stale), but it came
    assert store.in_order == {2: (3, 7), 3: (1, 0)}
    assert store.received == 3 and store.repeats == 1 and store.validator.stale == 1
    store.clear(2)  # robot 2 gone: a copy of 7 that comes later is kept, not counted again
    store.add(2, plan(2, 7))
    cursor[0] = 11
    store.add(2, plan(2, 8))
    assert store.in_order == {2: (4, 8), 3: (1, 0)} and store.received == 5
