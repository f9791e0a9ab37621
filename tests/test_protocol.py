"""The acceptance policy per message kind, the fault injector, and both in real runs.

Unit tests check every row of :mod:`services.protocol`'s table; the process
tests forge, duplicate and replay messages into a real run over Zenoh on
loopback and lose messages with the transport's fault injector, and assert
that the loops neither stall nor rewind (no lockstep timeout, every sample
run, no collision).
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from services.faults import ENV, FaultInjector, FaultSpec, kind_of_key
from services.messages import CmdMsg, DoneMsg, PlanMsg, StateMsg, decode, encode
from services.node import scenario_digest
from services.protocol import AcceptancePolicy, StateCursor, Verdict
from services.testing import Probe, free_ports, start_service, stop_processes
from sqpmpc.problem.scenario_file import load_scenario
from tests import HANG

K, TS, N = 100, 0.5, 8
POLICY = AcceptancePolicy(K, TS, N)
A, REP, ST, REF = Verdict.ACCEPT, Verdict.REPEAT, Verdict.STALE, Verdict.REFUSE


def _walk(samples: list[int]) -> tuple[list[Verdict], StateCursor]:
    """Feed states of ``samples`` (time consistent) to a fresh cursor."""
    cursor, out = StateCursor(), []
    for k in samples:
        d = POLICY.state(cursor, k, k * TS)
        out.append(d.verdict)
        if d.accepted:
            POLICY.advance(cursor, k)
    return out, cursor


# ------------------------------------------------------------------------- state
def test_state_in_order_repeat_and_replay():
    verdicts, cursor = _walk([0, 1, 1, 2, 0, 1, 3])
    assert verdicts == [A, A, REP, A, ST, ST, A]
    assert cursor.sample == 3 and cursor.asked is None


@pytest.mark.parametrize("sample", [K, K + 1, 2**62, -1])
def test_state_outside_the_run_is_refused_and_moves_nothing(sample):
    cursor = StateCursor(5)
    assert POLICY.state(cursor, sample, sample * TS).verdict is REF
    assert cursor.sample == 5


def test_state_with_an_inconsistent_time_is_refused():
    assert POLICY.state(StateCursor(), 4, 4 * TS + 1e-3).verdict is REF
    assert POLICY.state(StateCursor(), 4, 4 * TS).verdict is A


def test_a_forged_future_state_costs_one_step_and_cannot_lock_the_stream():
    # the plant is at 11; forged states of samples K - 2, K - 1 (consistent times) arrive;
    # the plant, still waiting for 12, publishes it again
    verdicts, cursor = _walk([10, 11, K - 2, K - 1, 12, 12, 13, 14])
    assert verdicts == [A, A, A, A, ST, A, A, A]
    assert cursor.sample == 14 and cursor.asked is None


def test_a_replayed_old_state_is_stale_once_and_costs_at_most_a_step():
    verdicts, cursor = _walk([0, 1, 2, 3, 1, 4, 0, 0, 1])
    assert verdicts == [A, A, A, A, ST, A, ST, A, A]
    assert cursor.sample == 1


def test_lost_states_are_skipped():
    verdicts, cursor = _walk([0, 1, 4, 5])
    assert verdicts == [A, A, A, A] and cursor.sample == 5


# ------------------------------------------------------------------------- cmd
def test_cmd_only_for_the_plants_current_sample():
    assert POLICY.cmd(7, 7).verdict is A
    assert POLICY.cmd(7, 6).verdict is ST  # late: counted, not applied
    assert POLICY.cmd(7, 8).verdict is REF
    assert POLICY.cmd(7, 2**62).verdict is REF


# ------------------------------------------------------------------------- plan
def test_plan_window_and_repeats():
    c = 50
    assert POLICY.plan(c, c - 1, held=False).verdict is A
    assert POLICY.plan(c, c - 1, held=True).verdict is REP
    assert POLICY.plan(c, c + N + 2, held=False).verdict is A
    assert POLICY.plan(c, c + N + 3, held=False).verdict is REF
    assert POLICY.plan(c, c - N - 1, held=False).verdict is A
    assert POLICY.plan(c, c - N - 2, held=False).verdict is ST
    assert POLICY.plan(K - 3, K, held=False).verdict is REF  # beyond the run
    assert POLICY.plan(-1, 0, held=False).verdict is A  # before the first state


# ------------------------------------------------------------------------- done
def test_done_only_within_the_run_and_after_the_cursor():
    assert POLICY.done(StateCursor(K - 1), K, True).accepted
    assert POLICY.done(StateCursor(40), 40, False).accepted  # the plant was stopped
    assert POLICY.done(StateCursor(40), 39, False).verdict is REF  # older than the states
    assert POLICY.done(StateCursor(40), K + 1, False).verdict is REF
    assert POLICY.done(StateCursor(40), 2**62, True).verdict is REF
    assert POLICY.done(StateCursor(40), 60, True).verdict is REF  # completed before K


# ------------------------------------------------------------------------- faults
def test_fault_spec_parsing_and_errors():
    spec = FaultSpec.parse("drop=0.2, delay=2, seed=7, kinds=plan+cmd")
    assert spec == FaultSpec(0.2, 2, 7, ("plan", "cmd")) and spec.active
    assert not FaultSpec.parse("").active
    for bad, word in (("drop=2", "drop"), ("delay=-1", "delay"), ("kinds=plans", "kinds"),
                      ("speed=1", "unknown"), ("drop", "key=value"), ("drop=x", "drop=x")):
        with pytest.raises(ValueError, match=word):
            FaultSpec.parse(bad)
    assert FaultInjector.from_env("robot/1", {ENV: "drop=0"}) is None
    assert FaultInjector.from_env("robot/1", {}) is None
    with pytest.raises(ValueError, match="mute"):
        FaultSpec.parse("mute=-1")


def test_a_muted_process_publishes_nothing_from_its_sample_on():
    """``mute=N``: silent once a state of sample N was seen, not before."""
    inj = FaultInjector(FaultSpec.parse("mute=3"), "robot/2")
    assert FaultSpec.parse("mute=3").active and not inj.muted()
    for k in range(3):
        inj.admit("state", encode(StateMsg(k, k * TS, (1,), np.zeros((1, 3)))), k)
        assert not inj.muted()
    inj.admit("state", encode(StateMsg(3, 3 * TS, (1,), np.zeros((1, 3)))), 3)
    assert inj.muted()


def test_fault_injector_drops_at_the_rate_and_delays_by_samples():
    inj = FaultInjector(FaultSpec(drop=0.2, seed=3, kinds=("plan",)), "robot/1")
    delivered = sum(len(inj.admit("plan", b"", i)) for i in range(20000))
    assert 0.18 < 1.0 - delivered / 20000 < 0.22 and inj.dropped == 20000 - delivered
    assert inj.admit("cmd", b"", "c") == ["c"]  # other kinds untouched
    inj = FaultInjector(FaultSpec(delay=2, kinds=("plan",)), "robot/1")

    def state(k: int) -> bytes:
        return encode(StateMsg(k, k * TS, (1,), np.zeros((1, 3))))

    assert inj.admit("state", state(0), "s0") == ["s0"]
    assert inj.admit("plan", b"", "p0") == []
    assert inj.admit("state", state(1), "s1") == ["s1"]
    assert inj.admit("state", state(2), "s2") == ["p0", "s2"]  # two samples later
    assert inj.admit("state", state(2**62), "forged") == ["forged"]  # cannot jump the clock
    assert inj.clock == 2
    assert kind_of_key(["robot", "3", "plan", "4"]) == "plan"
    assert kind_of_key(["plant", "done"]) == "done" and kind_of_key(["alive", "x"]) is None


# ------------------------------------------------------------------- real runs
SCENARIO = "paper-s2"


def _run(tmp_path, t_end: float, env: dict[str, str] | None = None,
         plant_args: tuple[str, ...] = (), robot_args: tuple[str, ...] = ()):
    ports = free_ports(6)
    probe_ep, plant_ep = (f"tcp/127.0.0.1:{p}" for p in ports[:2])
    probe = Probe("proto", [], [("plant", "state")], listen=[probe_ep])
    common = ["--scenario", SCENARIO, "--t-end", str(t_end), "--run", "proto"]
    full_env = {**os.environ, **(env or {})}
    plant = start_service("plant", [*common, "--listen", plant_ep, "--connect", probe_ep,
                                    "--out", str(tmp_path / "out"), "--no-plots", *plant_args],
                          tmp_path / "logs", env=full_env)
    robots = [start_service("robot", ["--id", str(i), *common, "--insecure", "--listen",
                                      f"tcp/127.0.0.1:{port}", "--connect", plant_ep,
                                      *robot_args],
                            tmp_path / "logs", name=f"robot-{i}", env=full_env)
              for i, port in zip((1, 2, 3, 4), ports[2:], strict=True)]
    return probe, plant, robots


def test_forged_duplicated_and_replayed_messages_neither_stall_nor_rewind(tmp_path):
    t_end = 40.0  # 80 samples
    # the plant's lockstep wait a hang guard: a timeout is a stall, never a busy machine
    probe, plant, robots = _run(tmp_path, t_end, plant_args=("--timeout", str(HANG)))
    procs = [plant, *robots]
    scenario = load_scenario(SCENARIO).with_changes(t_end=t_end)
    digest, ids = scenario_digest(scenario), tuple(int(i) for i in scenario.ids)
    x = scenario.initial_states()
    try:
        assert probe.wait_alive(["plant", "robot/1", "robot/2", "robot/3", "robot/4"], HANG)

        def reached(k: int) -> bool:
            return any(decode(e.payload, N).sample >= k for e in probe.events)

        assert probe.wait_for(lambda: reached(10), HANG), plant.output()
        replay = [e.payload for e in probe.events[:5]]
        forged = [
            StateMsg(2**62, 2**62 * TS, ids, x, None, digest),  # beyond the run
            StateMsg(78, 78 * TS, ids, x, None, digest),  # far future, consistent time
            StateMsg(79, 79 * TS, ids, x, None, digest),
        ]
        for msg in forged:
            probe.put(encode(msg), "plant", "state")
        for payload in replay:  # old states again
            probe.put(payload, "plant", "state")
        probe.put(encode(CmdMsg(1, 2**62, np.zeros(2), 0.0)), "robot", 1, "cmd")
        probe.put(encode(PlanMsg(2, 2**62, 0.0, 0.0, np.zeros((N + 1, 3)),
                                 np.zeros((N, 2)))), "robot", 2, "plan")
        probe.put(encode(DoneMsg(2**62, True)), "plant", "done")
        probe.put(encode(DoneMsg(3, True)), "plant", "done")  # completed before the end
        assert plant.wait(HANG) == 0, plant.output()
        for r in robots:
            assert r.wait(HANG) == 0, r.output()
    finally:
        probe.close()
        stop_processes(procs)
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["completed"] is True and m["steps"] == 80
    assert m["lockstep_timeouts"] == 0 and m["collisions"] == 0
    assert m["missed_deadlines"] <= 8  # at most the samples a forged jump took from a robot
    assert m["invalid_messages"] >= 4 * 4  # each robot refused the 2**62 state, cmd, dones


def test_lockstep_goes_on_under_heavy_loss_of_every_kind(tmp_path):
    t_end = 20.0  # 40 samples
    env = {ENV: "drop=0.3,seed=5,kinds=state+cmd+plan"}
    probe, plant, robots = _run(tmp_path, t_end, env, plant_args=("--timeout", "2"),
                                robot_args=("--timeout", "0.5"))
    try:
        assert plant.wait(HANG) == 0, plant.output()
        for r in robots:
            assert r.wait(HANG) == 0, r.output()
    finally:
        probe.close()
        stop_processes([plant, *robots])
    m = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert m["completed"] is True and m["collisions"] == 0
    assert m["intersample_collisions"] == 0
    assert m["republished_states"] > 0  # the losses were recovered by asking again
    assert "Traceback" not in plant.output() + "".join(r.output() for r in robots)
