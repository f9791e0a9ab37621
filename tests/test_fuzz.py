"""Property-based fuzzing of the two parsers of untrusted input.

- the message decoder and validator (:mod:`services.messages`): any payload
  either decodes to a message or raises :class:`InvalidMessage`, nothing else;
- the scenario loader (:mod:`sqpmpc.problem.scenario` from TOML text): any text either
  gives a :class:`Scenario` within the size limits or raises one
  :class:`ScenarioError`, nothing else.

Inputs are random bytes, random msgpack values, and mutations of valid
messages and scenario files (the fields that size arrays and loops set to
extreme numbers). ``SQPMPC_FUZZ_EXAMPLES`` sets the number of examples per
property (default 1000; ``benchmarks/faults.py`` runs 10,000).
"""

from __future__ import annotations

import json
import math
import os
import tomllib

import msgpack
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from services.messages import (
    CmdMsg,
    DoneMsg,
    InvalidMessage,
    PlanMsg,
    StateMsg,
    encode,
)
from services.protocol import AcceptancePolicy, StateCursor, Verdict
from services.validator import MessageValidator
from sqpmpc.errors import ScenarioError
from sqpmpc.problem.scenario import (
    MAX_HORIZON,
    MAX_ROBOT_SAMPLES,
    MAX_ROBOTS,
    MAX_STEPS,
    MIN_SAMPLE_TIME,
    Scenario,
)
from sqpmpc.problem.scenario_file import load_scenario, parse_scenario_text

EXAMPLES = int(os.environ.get("SQPMPC_FUZZ_EXAMPLES", "1000"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
N = 8
IDS = (1, 2, 3, 4)

# numbers that break naive code: huge, tiny, negative, non-finite, boundary integers
EXTREME_INTS = st.sampled_from([0, -1, 1, 2**31, 2**53 + 1, 2**62, 2**63 - 1, -(2**63),
                                2**64 - 1, MAX_HORIZON + 1, MAX_ROBOTS + 1, MAX_STEPS + 1])
EXTREME_FLOATS = st.sampled_from([0.0, -0.0, 1e-300, 5e-324, 1e-9, 1e308, -1e308, math.inf,
                                  -math.inf, math.nan, 2.0**62, MIN_SAMPLE_TIME / 2])
ANY_NUMBER = st.one_of(st.integers(-(2**63), 2**64 - 1),
                       st.floats(allow_nan=True, allow_infinity=True), EXTREME_INTS,
                       EXTREME_FLOATS)
LEAF = st.one_of(st.none(), st.booleans(), ANY_NUMBER, st.text(max_size=20),
                 st.binary(max_size=80))
MSGPACK_VALUE = st.recursive(
    LEAF, lambda inner: st.one_of(st.lists(inner, max_size=6),
                                  st.dictionaries(st.text(max_size=10), inner, max_size=6)),
    max_leaves=30)


def _valid_messages() -> list[bytes]:
    rng = np.random.default_rng(0)
    return [encode(StateMsg(3, 1.5, IDS, rng.normal(size=(4, 3)), 0.1, "abc")),
            encode(CmdMsg(2, 3, rng.normal(size=2), 0.01, None, 0, {"samples": 3})),
            encode(PlanMsg(2, 3, 1.5, 1.7e9, rng.normal(size=(N + 1, 3)),
                           rng.normal(size=(N, 2)))),
            encode(DoneMsg(80, True)),
            # the plan ages a cmd carries and the plant relays with the next states
            encode(CmdMsg(2, 3, rng.normal(size=2), 0.01, None, 0,
                          plan_ages={1: 2, 4: 3})),
            encode(StateMsg(4, 2.0, IDS, rng.normal(size=(4, 3)), None, "abc",
                            plan_ages={2: {1: 2, 4: 3}, 3: {1: N + 2}}))]


VALID = _valid_messages()


def _check_payload(payload: bytes) -> None:
    validator = MessageValidator(IDS, N, "abc")
    policy = AcceptancePolicy(80, 0.5, N)
    for kind, key_id in (("state", None), ("cmd", 2), ("plan", 2), ("done", None), (None, None)):
        try:
            msg = validator.check(payload, kind, key_id)
        except InvalidMessage:
            continue
        # a message that passes is well formed: the policy decides on it without raising
        if isinstance(msg, StateMsg | CmdMsg):  # relayed plan ages: known pairs, in range
            relay = (msg.plan_ages or {}) if isinstance(msg, StateMsg) else {
                msg.id: msg.plan_ages or {}}
            for rid, ages in relay.items():
                assert rid in IDS and all(j in IDS and j != rid and 1 <= a <= N + 2
                                          for j, a in ages.items())
        if isinstance(msg, StateMsg):
            assert msg.x.shape == (4, 3) and np.isfinite(msg.x).all()
            assert isinstance(policy.state(StateCursor(10), msg.sample, msg.t).verdict, Verdict)
        elif isinstance(msg, CmdMsg):
            assert msg.u.shape == (2,) and np.isfinite(msg.u).all()
            assert isinstance(policy.cmd(10, msg.sample).verdict, Verdict)
        elif isinstance(msg, PlanMsg):
            assert msg.states.shape == (N + 1, 3) and msg.inputs.shape == (N, 2)
            assert isinstance(policy.plan(10, msg.sample, False).verdict, Verdict)
        elif isinstance(msg, DoneMsg):
            assert isinstance(policy.done(StateCursor(10), msg.sample, msg.completed).verdict,
                              Verdict)
    assert validator.invalid <= 5


@FUZZ
@given(st.binary(max_size=2048))
def test_random_bytes_decode_or_raise_invalid_message(payload):
    _check_payload(payload)


@FUZZ
@given(MSGPACK_VALUE)
def test_random_msgpack_values_decode_or_raise_invalid_message(value):
    _check_payload(msgpack.packb(value, use_bin_type=True))


@FUZZ
@given(st.sampled_from(range(len(VALID))), st.data())
def test_mutated_messages_decode_or_raise_invalid_message(index, data):
    body = msgpack.unpackb(VALID[index], raw=False)
    keys = sorted(body)
    for _ in range(data.draw(st.integers(1, 3))):
        key = data.draw(st.sampled_from([*keys, "extra"]))
        if data.draw(st.booleans()) and key in body:
            del body[key]
        else:
            body[key] = data.draw(MSGPACK_VALUE)
    _check_payload(msgpack.packb(body, use_bin_type=True))


@FUZZ
@given(st.sampled_from(range(len(VALID))), st.integers(0, 400), st.binary(min_size=1,
                                                                          max_size=8))
def test_corrupted_bytes_decode_or_raise_invalid_message(index, at, junk):
    payload = VALID[index]
    at = at % len(payload)
    _check_payload(payload[:at] + junk + payload[at + len(junk):])
    _check_payload(payload[:at])  # truncated


# ------------------------------------------------------------------------ scenarios
BASE = load_scenario("paper-s2").to_toml()
BASE_DATA = tomllib.loads(BASE)
SCENARIO_KEYS = ["name", "t_end", "sample_time", "horizon", "weights", "bounds", "robots",
                 "weights.Q", "weights.R", "bounds.v", "bounds.omega", "bounds.x",
                 "robots.id", "robots.initial_state", "robots.diameter", "robots.reference",
                 "robots.reference.type", "robots.reference.omega", "robots.reference.x",
                 "robots.reference.position", "robots.reference.times",
                 "robots.reference.points"]
TOML_VALUE = st.recursive(
    st.one_of(st.booleans(), st.integers(-(2**63), 2**63 - 1), st.floats(),
              EXTREME_FLOATS, EXTREME_INTS.filter(lambda i: -(2**63) <= i < 2**63),
              st.text(max_size=12)),
    lambda inner: st.one_of(st.lists(inner, max_size=5),
                            st.dictionaries(st.text(min_size=1, max_size=8), inner, max_size=4)),
    max_leaves=12)


def _toml(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # JSON string escapes are TOML basic-string escapes
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_toml(k)} = {_toml(v)}" for k, v in value.items()) + "}"
    raise TypeError(type(value))


def _dump(data: dict) -> str:
    """A scenario dict as TOML text (top-level scalars, then tables, then robots)."""
    lines = [f"{k} = {_toml(v)}" for k, v in data.items() if k != "robots"]
    for robot in data.get("robots", []) if isinstance(data.get("robots"), list) else []:
        lines.append("[[robots]]\n" + "\n".join(f"{k} = {_toml(v)}" for k, v in
                                                   (robot.items() if isinstance(robot, dict)
                                                    else [])))
    if "robots" in data and not isinstance(data["robots"], list):
        lines.append(f"robots = {_toml(data['robots'])}")
    return "\n".join(lines) + "\n"


def _check_scenario_text(text: str | bytes) -> None:
    raw = text.encode() if isinstance(text, str) else text
    try:
        scenario = parse_scenario_text(raw, "fuzz.toml")
    except ScenarioError as exc:
        assert str(exc).startswith("fuzz.toml")
        return
    assert isinstance(scenario, Scenario)
    assert 1 <= scenario.horizon <= MAX_HORIZON and scenario.sample_time >= MIN_SAMPLE_TIME
    assert 1 <= scenario.steps <= MAX_STEPS and scenario.n_robots <= MAX_ROBOTS
    assert scenario.steps * scenario.n_robots <= MAX_ROBOT_SAMPLES


def _set(data: dict, path: str, value: object, robot: int) -> None:
    parts = path.split(".")
    node = data
    if parts[0] == "robots" and len(parts) > 1:
        robots = data.get("robots")
        if not isinstance(robots, list) or not robots or not isinstance(robots[0], dict):
            return
        node = robots[robot % len(robots)]
        parts = parts[1:]
    for p in parts[:-1]:
        child = node.get(p) if isinstance(node, dict) else None
        if not isinstance(child, dict):
            return
        node = child
    if isinstance(node, dict):
        node[parts[-1]] = value


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(SCENARIO_KEYS), TOML_VALUE, st.integers(0, 3)),
                min_size=1, max_size=4))
def test_mutated_scenarios_load_or_raise_one_scenario_error(mutations):
    data = tomllib.loads(BASE)
    for path, value, robot in mutations:
        _set(data, path, value, robot)
    _check_scenario_text(_dump(data))


@FUZZ
@given(st.sampled_from(["t_end", "sample_time", "horizon"]),
       st.one_of(EXTREME_INTS.filter(lambda i: -(2**63) <= i < 2**63), EXTREME_FLOATS,
                 st.floats(min_value=1e-12, max_value=1e12)))
def test_timing_extremes_are_refused_before_anything_is_sized(key, value):
    data = tomllib.loads(BASE)
    data[key] = value
    _check_scenario_text(_dump(data))


@FUZZ
@given(st.integers(0, len(BASE) - 1), st.text(max_size=12))
def test_corrupted_scenario_text_loads_or_raises_one_scenario_error(at, junk):
    _check_scenario_text(BASE[:at] + junk + BASE[at + len(junk):])


@settings(max_examples=max(1, EXAMPLES // 100), deadline=None, derandomize=True)
@given(st.sampled_from([MAX_ROBOTS + 1, 3000]))
def test_too_many_robots_are_refused_by_count(count):
    robot = BASE_DATA["robots"][0]
    lines = [_dump({k: v for k, v in BASE_DATA.items() if k != "robots"})]
    for i in range(count):
        r = {**robot, "id": i + 1, "initial_state": [float(i), 0.0, 0.0]}
        lines.append("[[robots]]\n" + "\n".join(f"{k} = {_toml(v)}" for k, v in r.items()))
    try:
        parse_scenario_text("\n".join(lines).encode(), "fuzz.toml")
    except ScenarioError as exc:
        assert exc.key == "robots" and str(MAX_ROBOTS) in str(exc)
    else:
        raise AssertionError("accepted too many robots")
