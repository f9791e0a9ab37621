"""Unit tests of the services' wire schema (services.messages) and key helpers."""

from __future__ import annotations

import argparse
import json
import math

import msgpack
import numpy as np
import pytest

from services.messages import (
    MAX_PAYLOAD,
    SCHEMA_VERSION,
    CmdMsg,
    DoneMsg,
    InvalidMessage,
    Mismatch,
    PlanMsg,
    StateMsg,
    decode,
    encode,
)
from services.transport import check_run_name, make_config, run_prefix
from services.validator import MessageValidator

IDS = (1, 2, 3, 4)
N = 8


def _validator(digest: str | None = "abc") -> MessageValidator:
    return MessageValidator(IDS, N, digest)


def _plan(rid: int = 2, sample: int = 3) -> PlanMsg:
    rng = np.random.default_rng(rid + sample)
    return PlanMsg(rid, sample, 0.5 * sample, 1.7e9, rng.normal(size=(N + 1, 3)),
                   rng.normal(size=(N, 2)))


def _state(sample: int = 0) -> StateMsg:
    x = np.arange(12, dtype=float).reshape(4, 3) / 7.0
    return StateMsg(sample, 0.5 * sample, IDS, x, None, "abc")


def _raw(body: dict) -> bytes:
    return msgpack.packb(body, use_bin_type=True)


def _body(msg) -> dict:
    return msgpack.unpackb(encode(msg), raw=False)


# ------------------------------------------------------------------------ round trip
def test_round_trip_is_bit_exact():
    plan = _plan()
    back = decode(encode(plan), N)
    assert isinstance(back, PlanMsg)
    assert back.id == plan.id and back.sample == plan.sample and back.t == plan.t
    assert np.array_equal(back.states, plan.states) and back.states.dtype == np.float64
    assert np.array_equal(back.inputs, plan.inputs)
    assert back.states.flags.writeable

    state = _state(5)
    back = decode(encode(state), N)
    assert back.ids == IDS and back.sample == 5 and back.budget is None
    assert np.array_equal(back.x, state.x)

    cmd = CmdMsg(3, 7, np.array([0.1 / 3, -math.pi / 7]), 0.00123, "brake", 4)
    back = decode(encode(cmd), N)
    assert back == CmdMsg(3, 7, back.u, 0.00123, "brake", 4, {})
    assert np.array_equal(back.u, cmd.u)

    assert decode(encode(DoneMsg(80, True)), N) == DoneMsg(80, True)


def test_every_message_carries_the_version():
    for msg in (_plan(), _state(), CmdMsg(1, 0, np.zeros(2), 0.0), DoneMsg(0, False)):
        assert _body(msg)["v"] == SCHEMA_VERSION


def test_unknown_extra_keys_are_ignored():
    body = _body(_state())
    body["future_field"] = [1, 2, 3]
    assert isinstance(decode(_raw(body), N), StateMsg)


# --------------------------------------------------------------------- malformed input
@pytest.mark.parametrize("payload", [
    b"",
    b"\x00garbage\xff\xfe",
    b"\xc1",  # a byte msgpack never uses
    _raw([1, 2, 3]),  # not a map
    _raw({1: "int key"}),
    b"\x92" + b"\x01" * 10,  # trailing data
])
def test_garbage_is_refused(payload):
    with pytest.raises(InvalidMessage):
        decode(payload, N)


def test_oversized_payload_is_refused():
    with pytest.raises(InvalidMessage, match="exceeds"):
        decode(b"\x00" * (MAX_PAYLOAD + 1), N)


@pytest.mark.parametrize("version", [None, 0, 2, "1", 1.0, True])
def test_wrong_version_is_refused(version):
    body = _body(_state())
    if version is None:
        del body["v"]
    else:
        body["v"] = version
    with pytest.raises(InvalidMessage, match="version"):
        decode(_raw(body), N)


def test_unknown_type_is_refused():
    body = _body(_state())
    body["type"] = "teleport"
    with pytest.raises(InvalidMessage, match="unknown message type"):
        decode(_raw(body), N)


@pytest.mark.parametrize("field,value", [
    ("x", np.array([[0.0, np.nan, 0.0]] * 4)),
    ("x", np.array([[0.0, np.inf, 0.0]] * 4)),
])
def test_non_finite_arrays_are_refused(field, value):
    body = _body(_state())
    body[field] = value.astype("<f8").tobytes()
    with pytest.raises(InvalidMessage, match="finite"):
        decode(_raw(body), N)


@pytest.mark.parametrize("field", ["t", "budget"])
def test_non_finite_scalars_are_refused(field):
    body = _body(_state())
    body[field] = float("nan")
    with pytest.raises(InvalidMessage, match="finite"):
        decode(_raw(body), N)


def test_nan_in_a_plan_and_a_cmd_is_refused():
    plan = _plan()
    states = plan.states.copy()
    states[4, 1] = np.nan
    with pytest.raises(InvalidMessage, match="finite"):
        decode(encode(PlanMsg(2, 3, 1.5, 0.0, states, plan.inputs)), N)
    with pytest.raises(InvalidMessage, match="finite"):
        decode(encode(CmdMsg(1, 0, np.array([np.nan, 0.0]), 0.0)), N)


def test_wrong_shapes_are_refused():
    plan = _plan()
    with pytest.raises(InvalidMessage, match="shape|bytes"):
        decode(encode(PlanMsg(2, 3, 1.5, 0.0, plan.states[:-1], plan.inputs)), N)
    with pytest.raises(InvalidMessage, match="bytes"):
        decode(encode(CmdMsg(1, 0, np.zeros(3), 0.0)), N)
    body = _body(_state())
    body["x"] = body["x"][:-8]
    with pytest.raises(InvalidMessage, match="bytes"):
        decode(_raw(body), N)
    # a plan of the right size for another horizon
    with pytest.raises(InvalidMessage):
        decode(encode(plan), N + 1)


@pytest.mark.parametrize("field,value", [
    ("sample", 1.0), ("sample", "3"), ("sample", -1), ("sample", True), ("sample", None),
    ("id", "2"), ("id", 2.0), ("id", False),
    ("t", "0.5"), ("stamp", None),
    ("states", [[0.0] * 3] * (N + 1)),  # lists instead of float64 bytes
    ("inputs", "not bytes"),
])
def test_wrong_types_in_a_plan_are_refused(field, value):
    body = _body(_plan())
    body[field] = value
    with pytest.raises(InvalidMessage):
        decode(_raw(body), N)


def test_cmd_counters_round_trip_and_default_to_empty():
    cmd = CmdMsg(3, 7, np.array([0.1, -0.2]), 1e-4, "brake", 2,
                 counters={"qp_rescues": 5, "gear_cycle_samples": 9})
    back = decode(encode(cmd), N)
    assert back.counters == {"qp_rescues": 5, "gear_cycle_samples": 9} and back.invalid == 2
    body = _body(cmd)
    del body["counters"]  # an older sender
    assert decode(_raw(body), N).counters == {}


@pytest.mark.parametrize("field,value", [
    ("compute_time", -1.0), ("fallback", 3), ("invalid", -2), ("u", None),
    ("counters", {"qp_rescues": -1}), ("counters", {"gear_cycle_samples": 1.5}),
    ("counters", {"x" * 65: 1}), ("counters", {str(i): 1 for i in range(65)}),
    ("counters", [1, 2]),
])
def test_wrong_values_in_a_cmd_are_refused(field, value):
    body = _body(CmdMsg(1, 0, np.zeros(2), 0.0))
    body[field] = value
    with pytest.raises(InvalidMessage):
        decode(_raw(body), N)


def test_plan_ages_round_trip_and_default_to_none():
    cmd = CmdMsg(3, 7, np.zeros(2), 1e-4, None, 0, plan_ages={1: 2, 4: N + 2})
    assert decode(encode(cmd), N).plan_ages == {1: 2, 4: N + 2}
    state = StateMsg(8, 4.0, IDS, np.zeros((4, 3)), None, "abc",
                     plan_ages={3: {1: 2, 4: 3}, 2: {}})
    assert decode(encode(state), N).plan_ages == {3: {1: 2, 4: 3}}  # empty: not sent
    assert decode(encode(_state()), N).plan_ages is None
    assert decode(encode(CmdMsg(1, 0, np.zeros(2), 0.0)), N).plan_ages is None


def test_measured_velocities_round_trip_bit_exact_and_are_checked():
    """The plant's measured velocities (acceleration bounds) travel with the states, bit
    for bit, so that the services step on what the in-process loop steps on; absent, none;
    a wrong size or a non-finite value is refused by name."""
    v = np.random.default_rng(5).normal(size=(4, 2))
    state = StateMsg(8, 4.0, IDS, np.zeros((4, 3)), None, "abc", v=v)
    back = decode(encode(state), N)
    assert back.v is not None and back.v.tobytes() == v.tobytes()
    assert decode(encode(_state()), N).v is None
    for bad in (np.zeros((3, 2)), np.full((4, 2), np.nan)):
        body = _body(StateMsg(8, 4.0, IDS, np.zeros((4, 3)), None, "abc", v=bad))
        with pytest.raises(InvalidMessage, match="velocities"):
            decode(_raw(body), N)


@pytest.mark.parametrize("value", [
    {}, [[1]], [[1, 2, 3]], [["1", 2]], [[1, 2.0]], [[1, 0]], [[1, N + 3]], [[1, 2], [1, 3]],
    [[1, True]], [[1, 2]] * 5000,
])
def test_wrong_plan_ages_in_a_cmd_are_refused(value):
    body = _body(CmdMsg(2, 0, np.zeros(2), 0.0))
    body["plan_ages"] = value
    with pytest.raises(InvalidMessage, match="plan_ages"):
        decode(_raw(body), N)


@pytest.mark.parametrize("value", [
    {}, [[1]], [[1, [[2, 2]], 3]], [["1", [[2, 2]]]], [[1, [[2, 0]]]], [[1, {}]],
    [[1, [[2, 2]]], [1, [[3, 2]]]], [[i, [[1, 2]] * 1000] for i in range(5)],
])
def test_wrong_plan_ages_in_a_state_are_refused(value):
    body = _body(_state())
    body["plan_ages"] = value
    with pytest.raises(InvalidMessage, match="plan_ages"):
        decode(_raw(body), N)


def test_validator_refuses_plan_ages_of_unknown_robots_or_of_oneself():
    v = _validator()
    for ages, match in (({7: 2}, "names robot 7"), ({2: 2}, "names robot 2")):
        with pytest.raises(InvalidMessage, match=match):
            v.check(encode(CmdMsg(2, 0, np.zeros(2), 0.0, plan_ages=ages)), "cmd", 2)
    x = np.zeros((4, 3))
    for ages, match in (({9: {1: 2}}, "unknown robot id 9"), ({1: {1: 2}}, "names robot 1"),
                        ({1: {5: 2}}, "names robot 5")):
        with pytest.raises(InvalidMessage, match=match):
            v.check(encode(StateMsg(0, 0.0, IDS, x, None, "abc", plan_ages=ages)), "state")
    assert v.invalid == 5
    ok = v.check(encode(StateMsg(0, 0.0, IDS, x, None, "abc", plan_ages={1: {2: 3}})),
                 "state")
    assert ok.plan_ages == {1: {2: 3}}


@pytest.mark.parametrize("ids", [[], [1, 2, "3", 4], "1234", None])
def test_bad_state_ids_are_refused(ids):
    body = _body(_state())
    body["ids"] = ids
    with pytest.raises(InvalidMessage):
        decode(_raw(body), N)


def test_done_needs_a_boolean():
    body = _body(DoneMsg(3, True))
    body["completed"] = 1
    with pytest.raises(InvalidMessage):
        decode(_raw(body), N)


# ------------------------------------------------------------------------- validator
def test_validator_counts_and_keeps_going():
    v = _validator()
    with pytest.raises(InvalidMessage):
        v.check(b"garbage", "cmd", 1)
    assert v.invalid == 1 and "msgpack" in v.last_error
    msg = v.check(encode(CmdMsg(1, 0, np.zeros(2), 0.0)), "cmd", 1)
    assert isinstance(msg, CmdMsg)
    assert v.invalid == 1
    v.refuse("unknown key")
    assert v.invalid == 2


def test_validator_refuses_unknown_and_mismatched_ids():
    v = _validator()
    with pytest.raises(InvalidMessage, match="unknown robot id 99"):
        v.check(encode(CmdMsg(99, 0, np.zeros(2), 0.0)), "cmd", None)
    with pytest.raises(InvalidMessage, match="key of robot 2"):
        v.check(encode(CmdMsg(1, 0, np.zeros(2), 0.0)), "cmd", 2)
    with pytest.raises(InvalidMessage, match="unknown robot id"):
        v.check(encode(_plan(rid=7)), "plan", None)
    assert v.invalid == 3


def test_validator_refuses_a_message_of_another_type_than_its_key():
    v = _validator()
    with pytest.raises(InvalidMessage, match="on a 'cmd' key"):
        v.check(encode(_plan(rid=1)), "cmd", 1)
    with pytest.raises(InvalidMessage, match="on a 'state' key"):
        v.check(encode(DoneMsg(1, True)), "state", None)


def test_validator_keeps_no_sample_order():
    # timeliness is the acceptance policy's (tests/test_protocol.py): the validator
    # checks form and identity only, so no sample index can lock a stream here
    v = _validator()
    for sample in (5, 5, 4, 2**62, 0):
        v.check(encode(_plan(rid=2, sample=sample)), "plan", 2)
        v.check(encode(_state(sample)), "state", None)
    assert v.invalid == 0


def test_validator_checks_state_ids_and_scenario_digest():
    v = _validator("abc")
    with pytest.raises(InvalidMessage, match="expected"):
        v.check(encode(StateMsg(0, 0.0, (2, 1, 3, 4), np.zeros((4, 3)), None, "abc")), "state")
    with pytest.raises(InvalidMessage, match="expected"):
        v.check(encode(StateMsg(0, 0.0, (1, 2, 3), np.zeros((3, 3)), None, "abc")), "state")
    with pytest.raises(InvalidMessage, match="digest"):
        v.check(encode(StateMsg(0, 0.0, IDS, np.zeros((4, 3)), None, "xyz")), "state")
    assert isinstance(v.check(encode(_state(0)), "state"), StateMsg)
    assert isinstance(_validator(None).check(encode(
        StateMsg(0, 0.0, IDS, np.zeros((4, 3)), 0.05, "other")), "state"), StateMsg)


def test_another_scenario_or_other_settings_is_a_mismatch_carrying_the_message():
    v = MessageValidator(IDS, N, "abc", "s1")
    with pytest.raises(Mismatch, match="scenario digest") as exc:  # also with other robots
        v.check(encode(StateMsg(0, 0.0, (1, 2), np.zeros((2, 3)), None, "xyz")), "state")
    assert isinstance(exc.value.msg, StateMsg) and exc.value.msg.scenario == "xyz"
    with pytest.raises(Mismatch, match="settings digest"):
        v.check(encode(StateMsg(0, 0.0, IDS, np.zeros((4, 3)), None, "abc", "s2")), "state")
    detail = {"collision_margin": "0.05", "process": "robot/2"}
    with pytest.raises(Mismatch) as exc:
        v.check(encode(CmdMsg(2, 0, np.zeros(2), 0.0, None, 0, None, "s2", detail)), "cmd", 2)
    assert exc.value.msg.detail == detail and exc.value.msg.settings == "s2"
    # the same digest, or none (an older sender, a probe): not checked
    assert v.check(encode(StateMsg(0, 0.0, IDS, np.zeros((4, 3)), None, "abc", "s1")), "state")
    assert v.check(encode(CmdMsg(2, 0, np.zeros(2), 0.0)), "cmd", 2).settings == ""
    with pytest.raises(InvalidMessage, match="detail"):
        v.check(encode(CmdMsg(2, 0, np.zeros(2), 0.0, None, 0, None, "s1",
                              {str(i): "x" for i in range(40)})), "cmd", 2)


def test_the_settings_digest_names_what_differs():
    from services.agreement import agreed_settings, describe_difference, settings_digest
    from sqpmpc.cli.options import add_controller_options, resolve_options, with_overrides
    from sqpmpc.problem.scenario_file import load_scenario

    parser = argparse.ArgumentParser()
    add_controller_options(parser, all_plans=True)

    def agreed(*argv: str) -> dict[str, str]:
        options = resolve_options(parser.parse_args(list(argv)))
        return agreed_settings(with_overrides(load_scenario("head-on"), options),
                               "decentralized", options)

    plant, same = agreed(), agreed("--collision-margin", "0.001", "--qp-solver", "osqp+piqp")
    assert settings_digest(plant) == settings_digest(same)  # the defaults, resolved
    robot = agreed("--collision-margin", "0.05", "--t-end", "4")
    assert settings_digest(robot) != settings_digest(plant)
    text = describe_difference(plant, {**robot, "process": "robot/2"}, "robot/2")
    assert text.startswith("robot/2 runs with collision_margin 0.05 (the plant: 0.001), "
                           "t_end 4 (the plant: 30)")
    assert "scenario" not in text.split(":")[0] and "--settings" in text


# ------------------------------------------------------------------------ key helpers
@pytest.mark.parametrize("name", ["a", "run-1", "paper_s2.v2", "x" * 64])
def test_valid_run_names(name):
    assert check_run_name(name) == name
    assert run_prefix(name) == f"sqpmpc/@v1/{name}"


@pytest.mark.parametrize("name", ["", "a/b", "*", "**", "a b", "$x", "@v1", "x" * 65, ".."])
def test_invalid_run_names(name):
    with pytest.raises(ValueError):
        check_run_name(name)


def test_config_is_loopback_peer_without_multicast():
    conf = make_config(["tcp/127.0.0.1:7447"], ["tcp/127.0.0.1:7448"])
    assert json.loads(conf.get_json("mode")) == "peer"
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7448"]
    default = make_config()
    assert json.loads(default.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    client = make_config(connect=["tcp/127.0.0.1:7447"], mode="client")
    assert json.loads(client.get_json("mode")) == "client"
    with pytest.raises(ValueError):
        make_config(mode="broker")
